"""Optional bearer-token auth for everything under ``/v1`` (HTTP and the WebSocket handshake).

Enforced in middleware, before the body is read, so an unauthenticated request is a 401 whatever
its body. ``bearer_scheme`` only documents the scheme in the OpenAPI schema.
"""

from __future__ import annotations

import hmac
from urllib.parse import parse_qs

from fastapi.security import HTTPBearer
from starlette.types import ASGIApp, Receive, Scope, Send

from service.api.middleware import send_json
from service.wire.errors import UnauthorizedError

PROTECTED_PREFIX = "/v1/"

bearer_scheme = HTTPBearer(auto_error=False, description="set when the server has an auth_token")


def token_matches(given: str | None, expected: str) -> bool:
    return given is not None and hmac.compare_digest(given.encode(), expected.encode())


def bearer_token(scope: Scope) -> str | None:
    """The token of an ``Authorization: Bearer`` header, or (WebSockets only: browsers cannot set
    headers there) of a ``token`` query parameter."""
    for key, value in scope.get("headers", []):
        if key == b"authorization":
            scheme, _, token = value.decode("latin-1").partition(" ")
            if scheme.lower() == "bearer":
                return token.strip()
    if scope["type"] == "websocket":
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        tokens = query.get("token")
        return tokens[0] if tokens else None
    return None


class BearerAuthMiddleware:
    def __init__(self, app: ASGIApp, token: str | None) -> None:
        self.app = app
        self.token = token

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        protected = scope["type"] in ("http", "websocket") and scope.get("path", "").startswith(
            PROTECTED_PREFIX
        )
        if not self.token or not protected or token_matches(bearer_token(scope), self.token):
            await self.app(scope, receive, send)
            return
        if scope["type"] == "websocket":
            # Refuse the handshake (the server answers 403); 1008 = policy violation.
            await send({"type": "websocket.close", "code": 1008, "reason": "unauthorized"})
            return
        error = UnauthorizedError()
        await send_json(send, 401, error.payload(), error.headers)
