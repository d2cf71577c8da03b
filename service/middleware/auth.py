"""Bearer-token auth for every path but the open ones (health checks; /metrics and /docs if asked)."""

from __future__ import annotations

import hashlib
import hmac

from ..http import error_reply

CLIENT = "client_id"  # the scope["state"] key naming an authenticated client, for the rate limit


class BearerAuth:
    """ASGI middleware: 401 without an `Authorization: Bearer <token>` header, 403 with a token not accepted.

    Tokens are compared in constant time. An accepted request carries the token's short hash in
    scope["state"][CLIENT], so the rate limit counts per token rather than per address.
    """

    def __init__(self, app, *, tokens: frozenset[str], open_paths: frozenset[str], open_prefixes: tuple[str, ...] = ()):
        self.app, self.open_paths, self.open_prefixes = app, open_paths, open_prefixes
        self.tokens = [token.encode() for token in sorted(tokens)]

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket") or self._open(scope["path"]):
            return await self.app(scope, receive, send)
        token = _bearer(dict(scope["headers"]).get(b"authorization", b""))
        if scope["type"] == "websocket":  # the estimate stream: the same tokens, refused at the handshake (HTTP 403)
            if token is None or not self._accepted(token):
                await receive()  # websocket.connect
                return await send({"type": "websocket.close", "code": 1008})
            scope.setdefault("state", {})[CLIENT] = "token:" + hashlib.sha256(token).hexdigest()[:12]
            return await self.app(scope, receive, send)
        if token is None:
            reply = error_reply(401, [("authorization", "authorization: send `Authorization: Bearer <token>`",
                                       "missing_token")], headers={"WWW-Authenticate": 'Bearer realm="deform"'})
            return await reply(scope, receive, send)
        if not self._accepted(token):
            reply = error_reply(403, [("authorization", "authorization: this bearer token is not accepted",
                                       "invalid_token")], headers={"WWW-Authenticate": 'Bearer error="invalid_token"'})
            return await reply(scope, receive, send)
        scope.setdefault("state", {})[CLIENT] = "token:" + hashlib.sha256(token).hexdigest()[:12]
        await self.app(scope, receive, send)

    def _open(self, path: str) -> bool:
        return path in self.open_paths or path.startswith(self.open_prefixes)

    def _accepted(self, token: bytes) -> bool:
        # compare with every token, so the time taken does not say which one nearly matched
        return sum(hmac.compare_digest(token, known) for known in self.tokens) > 0


def _bearer(header: bytes) -> bytes | None:
    """The token of an `Authorization: Bearer <token>` header (scheme case-insensitive), or None."""
    scheme, _, token = header.strip().partition(b" ")
    token = token.strip()
    return token if scheme.lower() == b"bearer" and token else None
