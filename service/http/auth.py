"""The token check every /api router but health depends on.

GET/HEAD need the ``read`` scope, other methods ``operate``, anything under /api/admin ``admin``.
The token comes from ``Authorization: Bearer <token>``; ``?token=`` is accepted only on the job
event stream (/api/jobs/{id}/events), because a browser's EventSource cannot send headers.
Refusals are 401 (no, unknown or revoked token) or 403 (scope too low), in the API's error format.
The access log shows such a query token as ``token=***``.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable
from functools import partial

from fastapi import Depends, FastAPI, Request
from fastapi.responses import JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from service.security.auth import AuthError, RecentTokens, authenticate, authorize, required_scope, still_valid

#: A token in a query string, as written to the access log.
QUERY_TOKEN = re.compile(r"(?<=[?&]token=)[^&\s]+")
#: The only path that takes ``?token=`` (SSE: EventSource cannot set headers).
QUERY_TOKEN_PATH = re.compile(r"^/api/jobs/[^/]+/events$")
#: When auth is off every request acts with this record.
AUTH_OFF = {"id": None, "name": "auth off", "scope": "admin", "origin": None, "scopes": ["read", "operate", "admin"]}

BEARER = HTTPBearer(
    auto_error=False,
    description="An API token: `evcbench token create`, or <data_dir>/admin.token on the service's machine",
)


def require_token(request: Request, credentials: HTTPAuthorizationCredentials | None = Depends(BEARER)) -> dict:
    """The caller's token record; AuthError (401/403) if it may not make this request."""
    if request.app.state.settings.auth == "off":
        return AUTH_OFF
    path = request.url.path
    token = credentials.credentials if credentials else None
    query_token = request.query_params.get("token")
    if token is None and query_token is not None:
        if not QUERY_TOKEN_PATH.match(path):
            raise AuthError(
                401,
                "?token= is accepted only on /api/jobs/{id}/events; send the header 'Authorization: Bearer <token>'",
                field="token",
            )
        token = query_token
    try:
        record = authenticate(request.app.state.store, token)
    except AuthError:
        if token:
            recent_tokens(request.app).forget_token(token)  # revoked elsewhere: the stop refuses it too
        raise
    recent_tokens(request.app).remember(token, record)
    authorize(record, required_scope(request.method, path))
    return record


def require_token_for_stop(request: Request, credentials: HTTPAuthorizationCredentials | None) -> dict:
    """``require_token`` for the emergency stop: a token this process verified lately is taken from
    memory, without a store read (``RecentTokens`` says why, and what it allows); any other goes
    through the store as on every route."""
    if request.app.state.settings.auth != "off" and credentials is not None:
        record = recent_tokens(request.app).recent(credentials.credentials)
        if record is not None:
            authorize(record, required_scope(request.method, request.url.path))
            return record
    return require_token(request, credentials)


def recent_tokens(app: FastAPI) -> RecentTokens:
    """The app's ``RecentTokens`` (``install`` makes it)."""
    return app.state.recent_tokens


#: Pass to include_router(dependencies=…) for every router that needs a token.
REQUIRE_TOKEN = [Depends(require_token)]
#: The refusals a route that checks its token itself documents (``responses=``).
AUTH_ERRORS = {401: {"description": "no, unknown or revoked token"}, 403: {"description": "scope too low"}}


def token_recheck(request: Request, record: dict) -> Callable[[], str | None] | None:
    """For a long response (the event stream): a callable that says why the caller's token is no
    longer valid (revoked, deleted), or None while it is; None when auth is off. It reads the store:
    call it off the event loop."""
    if request.app.state.settings.auth == "off" or record.get("id") is None:
        return None
    return partial(still_valid, request.app.state.store, record)


class RedactQueryToken(logging.Filter):
    """Replace ``token=<secret>`` in access-log arguments by ``token=***`` (the record is kept)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple):
            record.args = tuple(QUERY_TOKEN.sub("***", a) if isinstance(a, str) else a for a in record.args)
        return True


_REDACT = RedactQueryToken()


def install(app: FastAPI) -> None:
    """Turn AuthError into the API's error body ``{"detail", "field"}`` (+ WWW-Authenticate on 401),
    and keep query tokens out of uvicorn's access log; the tokens verified lately start empty."""
    app.state.recent_tokens = RecentTokens()
    access_log = logging.getLogger("uvicorn.access")
    if _REDACT not in access_log.filters:
        access_log.addFilter(_REDACT)

    @app.exception_handler(AuthError)
    async def _auth(_request: Request, exc: AuthError) -> JSONResponse:
        headers = {"WWW-Authenticate": "Bearer"} if exc.status_code == 401 else None
        return JSONResponse(
            status_code=exc.status_code, content={"detail": exc.detail, "field": exc.field}, headers=headers
        )
