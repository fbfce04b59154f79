"""Who may use the console's API: a random token (a file in the state directory), the Origin
of state-changing requests, a rate limit on moves.

Every ``/api`` request needs ``Authorization: Bearer TOKEN`` (checked before anything else:
401); a state-changing request whose ``Origin`` is not the console's own gets 403 (no
``Origin``, as scripts send, passes on the token); the WebSocket's first message must be
``{"token": TOKEN}``.  Moves, jogs and calibrations are rate-limited (429).
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import os
import secrets
import threading
import time
from collections.abc import Callable
from pathlib import Path

from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send
from starlette.websockets import WebSocket, WebSocketDisconnect

from feeder.errors import InputError
from feeder.web.requests import error_response

TOKEN_FILE = "http-token"
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
PUBLIC_PATHS = frozenset({"/", "/plate_view.js", "/console.js"})
"""What loads without the token: the page (static, no data)."""
WS_AUTH_TIMEOUT_S = 5.0
WS_UNAUTHORIZED = 4401
WS_FORBIDDEN = 4403


def new_token(state_dir: Path) -> str:
    """A fresh random token, written to ``state_dir/http-token`` (mode 0600, atomically)."""
    token = secrets.token_urlsafe(32)
    path = state_dir / TOKEN_FILE
    tmp = path.with_name(f".{TOKEN_FILE}.{os.getpid()}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o600)
        with os.fdopen(fd, "w") as handle:
            handle.write(token + "\n")
        os.chmod(tmp, 0o600)
        tmp.replace(path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise InputError(str(path), f"cannot write: {err.strerror or err}") from None
    return token


def token_matches(token: str, given: str | None) -> bool:
    """Constant-time comparison (a wrong token takes as long to refuse as a nearly right one)."""
    return given is not None and hmac.compare_digest(token.encode(), given.encode())


class RateLimit:
    """Token bucket: ``burst`` requests at once, then ``per_s`` a second."""

    def __init__(self, per_s: float, burst: int, clock: Callable[[], float] = time.monotonic) -> None:
        self.per_s = per_s
        self.burst = burst
        self._clock = clock
        self._tokens = float(burst)
        self._last = clock()
        self._lock = threading.Lock()

    def take(self) -> float:
        """0 when a request may go now (and counts it), else the seconds until one may."""
        with self._lock:
            now = self._clock()
            self._tokens = min(self.burst, self._tokens + (now - self._last) * self.per_s)
            self._last = now
            if self._tokens >= 1:
                self._tokens -= 1
                return 0.0
            return (1 - self._tokens) / self.per_s


class ApiGuard:
    """ASGI middleware in front of everything but the page (``/api`` and unknown paths alike):
    the token first (401), then the Origin of a state-changing request (403).  WebSockets
    authenticate in their first message (a browser cannot give them a header)."""

    def __init__(self, app: ASGIApp, token: str, origins: frozenset[str]) -> None:
        self.app = app
        self.token = token
        self.origins = origins

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["path"] in PUBLIC_PATHS:
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        scheme, _, given = headers.get("authorization", "").partition(" ")
        if scheme.lower() != "bearer" or not token_matches(self.token, given.strip()):
            response = error_response(
                401,
                "missing or wrong token: send 'Authorization: Bearer TOKEN' (the daemon prints the "
                f"console's address with it; it is also in the state directory's {TOKEN_FILE})",
                {"WWW-Authenticate": "Bearer"},
            )
        elif scope["method"] not in SAFE_METHODS and not origin_allowed(headers, self.origins):
            response = error_response(
                403, f"origin {headers.get('origin')!r} may not change the daemon's state"
            )
        else:
            await self.app(scope, receive, send)
            return
        await response(scope, receive, send)


def origin_allowed(headers: Headers, origins: frozenset[str]) -> bool:
    """No Origin header (a script), or one of the console's own origins."""
    origin = headers.get("origin")
    return origin is None or origin.rstrip("/") in origins


def own_origins(host: str, port: int, extra: tuple[str, ...] = ()) -> frozenset[str]:
    """The origins the page is served from: the bound address, and ``localhost`` for a loopback one."""
    names = {f"[{host}]" if ":" in host else host}
    if host in ("127.0.0.1", "::1", "localhost"):
        names |= {"127.0.0.1", "localhost", "[::1]"}
    return frozenset({f"http://{name}:{port}" for name in names} | set(extra))


async def websocket_admitted(ws: WebSocket, token: str, origins: frozenset[str]) -> bool:
    """Accepts ``ws`` when its Origin is allowed (else closes it: 4403) and its first message,
    within :data:`WS_AUTH_TIMEOUT_S`, is ``{"token": TOKEN}`` (else closes it: 4401)."""
    if not origin_allowed(ws.headers, origins):
        await ws.close(code=WS_FORBIDDEN)
        return False
    await ws.accept()
    try:
        hello = json.loads(await asyncio.wait_for(ws.receive_text(), WS_AUTH_TIMEOUT_S))
    except (TimeoutError, ValueError, KeyError, WebSocketDisconnect, RuntimeError):
        hello = None
    if not isinstance(hello, dict) or not token_matches(token, str(hello.get("token"))):
        with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
            await ws.send_text(json.dumps({"type": "error", "error": "wrong token"}))
            await ws.close(code=WS_UNAUTHORIZED)
        return False
    return True
