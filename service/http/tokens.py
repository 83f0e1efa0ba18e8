"""Token management (admin scope): GET/POST /api/admin/tokens, DELETE /api/admin/tokens/{id}."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request

from service.http.auth import recent_tokens
from service.http.deps import get_store
from service.http.schemas.admin import NewToken, Token, TokenRequest
from service.runtime.stop_port_link import refresh_stop_tokens
from service.security import auth
from service.store import NotFoundError, Store, utc_now

router = APIRouter(prefix="/admin/tokens", tags=["admin"])


@router.get("", response_model=list[Token])
def list_tokens(store: Store = Depends(get_store)) -> list[dict]:
    """Every token (revoked ones too): id, name, scope, scopes, origin, created_at, revoked. No secrets."""
    return [auth.public(t) for t in store.tokens.list()]


@router.post("", status_code=201, response_model=NewToken)
def create_token(body: TokenRequest, request: Request, store: Store = Depends(get_store)) -> dict:
    """Issue a token. Its plaintext is in ``token`` of this answer only: it is stored hashed."""
    plaintext, record = auth.issue(store, body.name, body.scope, "api")
    refresh_stop_tokens(request.app)
    return {**record, "token": plaintext}


@router.delete("/{token_id}", response_model=Token)
def revoke_token(token_id: str, request: Request, store: Store = Depends(get_store)) -> dict:
    """Revoke a token at once (the next request with it gets 401, the emergency stop's included)."""
    if not store.tokens.revoke(token_id, utc_now()):
        raise NotFoundError("token", token_id)
    recent_tokens(request.app).forget(token_id)
    refresh_stop_tokens(request.app)
    return auth.public(store.tokens.get(token_id))
