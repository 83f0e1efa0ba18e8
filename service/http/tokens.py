"""Token management (admin scope): GET/POST /api/admin/tokens, DELETE /api/admin/tokens/{id}."""
from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Depends
from pydantic import BaseModel, Field

from service.security import auth
from service.http.deps import get_store
from service.store import NotFoundError, Store, utc_now

router = APIRouter(prefix="/admin/tokens", tags=["admin"])


class TokenRequest(BaseModel):
    name: str = Field(min_length=1, max_length=200, description="who or what uses the token")
    scope: Literal["read", "operate", "admin"] = Field("read", description="read ⊂ operate ⊂ admin")


@router.get("")
def list_tokens(store: Store = Depends(get_store)) -> list[dict]:
    """Every token (revoked ones too): id, name, scope, scopes, origin, created_at, revoked. No secrets."""
    return [auth.public(t) for t in store.tokens.list()]


@router.post("", status_code=201)
def create_token(body: TokenRequest, store: Store = Depends(get_store)) -> dict:
    """Issue a token. Its plaintext is in ``token`` of this answer only: it is stored hashed."""
    plaintext, record = auth.issue(store, body.name, body.scope, "api")
    return {**record, "token": plaintext}


@router.delete("/{token_id}")
def revoke_token(token_id: str, store: Store = Depends(get_store)) -> dict:
    """Revoke a token at once (the next request with it gets 401)."""
    if not store.tokens.revoke(token_id, utc_now()):
        raise NotFoundError("token", token_id)
    return auth.public(store.tokens.get(token_id))
