"""Bearer-token authentication of the API's mutating calls (``--secure DIR``: the token is
``DIR/api.token``, made by ``fleet keys init``).

Every HTTP request that is not ``GET``, ``HEAD`` or ``OPTIONS`` must carry
``Authorization: Bearer <token>``; otherwise it is answered ``401`` with
``{"error", "field": "Authorization", "status": 401}`` and a ``WWW-Authenticate: Bearer``
header, before anything reads its body. Reads (and the WebSocket, which only streams) stay
open: serve the API on loopback when the fleet is secured (``docs/security.md``)."""

from __future__ import annotations

import hmac
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from fastapi.responses import JSONResponse

Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

#: Methods that change nothing and need no token.
READ_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


def _unauthorized(reason: str) -> JSONResponse:
    return JSONResponse(
        {"error": reason, "field": "Authorization", "status": 401},
        status_code=401,
        headers={"WWW-Authenticate": "Bearer"},
    )


class TokenGuard:
    """ASGI middleware: mutating HTTP calls need ``Authorization: Bearer <token>`` (see the
    module docstring); the token is compared in constant time."""

    def __init__(self, app: ASGIApp, token: str) -> None:
        if not token:
            raise ValueError("the API token is empty")
        self.app = app
        self._token = token.encode()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope.get("method", "GET") in READ_METHODS:
            await self.app(scope, receive, send)
            return
        given = b""
        for k, v in scope.get("headers", []):
            if k == b"authorization":
                given = bytes(v)
        scheme, _, value = given.partition(b" ")
        if not given:
            reason = (
                "this fleet is secured: send the API token as 'Authorization: Bearer <token>' (DIR/api.token)"
            )
        elif scheme.lower() != b"bearer" or not hmac.compare_digest(value.strip(), self._token):
            reason = "wrong API token (see DIR/api.token of `fleet keys init`)"
        else:
            await self.app(scope, receive, send)
            return
        await _unauthorized(reason)(scope, receive, send)
