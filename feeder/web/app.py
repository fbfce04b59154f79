"""The operator's console: one page in the browser, served by the daemon (docs/console.md).

Starlette on uvicorn, on its own thread in the daemon's process (never the tick's).
``GET /`` serves the page (static HTML and script, no data).  The JSON API mirrors
the socket's commands and answers by calling the daemon's own request handler
(:meth:`~feeder.daemon.service.Daemon.handle`), so the page, the CLI and scripts
share one vocabulary:

| route | request |
|---|---|
| ``GET /api/status`` | ``{"cmd": "status"}`` (shared by the requests within 40 ms) |
| ``GET /api/history?limit=N`` | ``{"cmd": "history", "limit": N}`` |
| ``POST /api/move`` | ``{"cmd": "move", ...body}`` (``target_m``, ``by_m``, or ``x_m``, ``y_m``,
  ``angle_rad``, ``part``) |
| ``POST /api/jog`` | ``{"axis", "steps"}``: a relative move by ``steps`` learned steps of one axis |
| ``POST /api/stop`` | ``{"cmd": "stop"}`` |
| ``POST /api/calibrate`` | ``{"cmd": "calibrate", ...body}`` |
| ``WS /api/live`` | pushes the status (JSON text, ``time_s`` = wall clock of the snapshot) at
  :data:`LIVE_PERIOD_S` and the newest camera frame (binary JPEG) when there is a camera |

Security: every ``/api`` request needs ``Authorization: Bearer TOKEN`` (checked
before anything else: 401); a state-changing request whose ``Origin`` is not the
console's own gets 403 (no ``Origin``, as scripts send, passes on the token);
the WebSocket's first message must be ``{"token": TOKEN}``.  Moves, jogs and
calibrations are rate-limited (429).  Bad requests get ``{"ok": false,
"error": ...}`` with a 4xx code; a refusal by the daemon is 409.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import math
import os
import secrets
import socket
import threading
import time
from collections.abc import Awaitable, Callable
from importlib import resources
from pathlib import Path
from typing import Any, Protocol

import uvicorn
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.types import ASGIApp, Receive, Scope, Send
from starlette.websockets import WebSocket, WebSocketDisconnect, WebSocketState

from feeder.daemon.client import MAX_LINE_BYTES
from feeder.daemon.config import HttpConfig
from feeder.errors import InputError

log = logging.getLogger(__name__)

TOKEN_FILE = "http-token"
LIVE_PERIOD_S = 1 / 30
"""Status pushes to each live client: 30 per second."""
STATUS_MAX_AGE_S = 0.025
"""A status snapshot is shared by the requests within this time of it."""
CAMERA_PERIOD_S = 1 / 60
"""The live view asks the camera for a new frame this often; it encodes each new frame once
(at most the camera's rate: 15 frames/s from the simulator)."""
CAMERA_MAX_SIDE_PX = 640
JPEG_QUALITY = 80
WS_AUTH_TIMEOUT_S = 5.0
MAX_JOG_STEPS = 10_000
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
WS_UNAUTHORIZED = 4401
WS_FORBIDDEN = 4403
STATIC = ("console.html", "console.js")
"""The page's files, package data of :mod:`feeder.web.static`."""
PUBLIC_PATHS = frozenset({"/", "/console.js"})
"""What loads without the token: the page (static, no data)."""


class Handler(Protocol):
    """What the console needs of the daemon: its request handler."""

    def handle(self, request: Any) -> dict[str, Any]: ...


ImageSource = Callable[[], Any]
"""Returns the newest camera image (numpy, grey or BGR) or None; may block up to ~1 s."""


class ApiError(Exception):
    """A request refused with an HTTP status and a one-line reason."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


def error_response(status: int, message: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"ok": False, "error": message}, status_code=status, headers=headers)


# -- token --------------------------------------------------------------------------
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


# -- rate limit -----------------------------------------------------------------------
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


# -- guard ---------------------------------------------------------------------------
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


# -- request bodies -------------------------------------------------------------------
async def json_body(request: Request) -> dict[str, Any]:
    """The body as a JSON object (empty body: ``{}``); 413/400 otherwise."""
    raw = bytearray()
    async for chunk in request.stream():
        raw += chunk
        if len(raw) > MAX_LINE_BYTES:
            raise ApiError(413, f"request body longer than {MAX_LINE_BYTES} bytes")
    if not raw.strip():
        return {}
    try:
        body = json.loads(bytes(raw))
    except (ValueError, RecursionError) as err:
        raise ApiError(400, f"malformed JSON: {type(err).__name__}: {str(err)[:200]}") from None
    if not isinstance(body, dict):
        raise ApiError(400, f"the body must be a JSON object, got {type(body).__name__}")
    return body


NUMBERS = frozenset({"target_m", "by_m", "x_m", "y_m", "angle_rad"})
FLAGS = frozenset({"queue", "wait", "trace"})
FIELDS = {
    "move": NUMBERS | FLAGS | {"part"},
    "calibrate": FLAGS | {"steps"},
    "stop": frozenset(),
    "jog": frozenset({"axis", "steps", "part"}),
}


def checked(cmd: str, body: dict[str, Any]) -> dict[str, Any]:
    """``body`` with its field types checked (the daemon checks ranges and combinations)."""
    for key, value in body.items():
        if key not in FIELDS[cmd]:
            known = ", ".join(sorted(FIELDS[cmd])) or "none"
            raise ApiError(400, f"unknown field {key!r} for {cmd}; known: {known}")
        if key in NUMBERS and (
            isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value)
        ):
            raise ApiError(400, f"{key} must be a finite number, got {json.dumps(value)[:40]}")
        if key in FLAGS and not isinstance(value, bool):
            raise ApiError(400, f"{key} must be true or false")
        if key in ("part", "steps") and (isinstance(value, bool) or not isinstance(value, int)):
            raise ApiError(400, f"{key} must be an integer")
    return body


# -- jog -----------------------------------------------------------------------------
def jog_request(status: dict[str, Any], axis: str, steps: int, part: int) -> dict[str, Any]:
    """The move request for ``steps`` learned steps (sign = direction) of ``axis``.

    On a plane (more than one axis in the status' ``axes``): the part's pose plus ``steps`` ×
    the axis' learned step (``axes[axis]["step_m"]``, ``["step_rad"]`` for theta); on one axis:
    ``by_m``, with the coarse step learned in that direction.
    """
    if not 0 < abs(steps) <= MAX_JOG_STEPS:
        raise ApiError(400, f"steps must be a non-zero integer within ±{MAX_JOG_STEPS}, got {steps}")
    parts = [p for p in status.get("parts") or () if p.get("pose") is not None]
    if len(status.get("axes") or ()) <= 1:  # one axis: today's feeder
        if axis != "x":
            raise ApiError(409, f"this daemon drives one axis (x); there is no {axis!r} to jog")
        name = "coarse/forward" if steps > 0 else "coarse/backward"
        step = status.get("estimates", {}).get(name, {}).get("step_m")
        if not isinstance(step, (int, float)):
            raise ApiError(409, "no learned step to jog with")
        return {"cmd": "move", "by_m": steps * step, "wait": False}
    axes = status.get("axes") or {}
    if axis not in axes:
        raise ApiError(400, f"axis must be one of {', '.join(axes)}, got {axis!r}")
    pose = next((p["pose"] for p in parts if p.get("id") == part), None)
    if pose is None:
        raise ApiError(400, f"no part {part}; parts: {', '.join(str(p.get('id')) for p in parts)}")
    key, index, field = {"x": ("step_m", 0, "x_m"), "y": ("step_m", 1, "y_m")}.get(
        axis, ("step_rad", 2, "angle_rad")
    )
    step = axes[axis].get(key) if isinstance(axes[axis], dict) else None
    if not isinstance(step, (int, float)):
        raise ApiError(409, f"no learned step of axis {axis} to jog with")
    return {"cmd": "move", "part": part, field: pose[index] + steps * step, "wait": False}


# -- live feed -----------------------------------------------------------------------
class CameraFeed:
    """Reads the newest camera image on its own thread and keeps it JPEG-encoded."""

    def __init__(self, source: ImageSource, close_source: Callable[[], None] = lambda: None) -> None:
        import cv2  # OpenCV (the optional vision extra): only with a camera

        self._cv2 = cv2
        self.source = source
        self._close_source = close_source
        self.jpeg: bytes | None = None
        self.size_px = (0, 0)
        """(width, height) of the camera's image before it was scaled down for the page."""
        self.sequence = 0
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="console-camera", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        cv2 = self._cv2
        began = -math.inf
        last: Any = None
        while not self._closed.wait(max(0.0, began + CAMERA_PERIOD_S - time.monotonic())):
            began = time.monotonic()
            try:
                image = self.source()
            except (OSError, RuntimeError) as err:  # CameraLost (a SensorLost), a closed link
                log.debug("console camera: %s", err)
                continue
            if image is None or image is last:  # no new frame since the last one sent
                continue
            last = image
            size_px = (int(image.shape[1]), int(image.shape[0]))
            scale = CAMERA_MAX_SIDE_PX / max(image.shape[:2])
            if scale < 1:
                image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            if image.dtype != "uint8":
                image = cv2.convertScaleAbs(image, alpha=255.0 / max(1, int(image.max())))
            ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            if ok:
                self.jpeg, self.size_px = data.tobytes(), size_px
                self.sequence += 1

    def close(self) -> None:
        self._closed.set()
        self._thread.join(timeout=2.0)
        self._close_source()


def camera_feed(spec: str | None, daemon: Any) -> CameraFeed | None:
    """The live view's camera: ``spec`` (an :func:`~feeder.drivers.video_camera.open_camera`
    spec: a URL, device index, folder), else the daemon's ``latest_image()`` where it has one
    (a camera pose sensor), else none: the page draws the plate from the poses alone."""
    try:
        if spec is not None:
            from feeder.drivers.video_camera import CameraError, open_camera

            try:
                frames = open_camera(spec)
            except CameraError as err:
                raise InputError("http.camera", str(err)) from None
            return CameraFeed(lambda: frames.read(1.0).image, frames.close)
        latest = getattr(daemon, "latest_image", None)
        if callable(latest):
            return CameraFeed(lambda: _image(latest()))
    except ImportError as err:
        raise InputError(
            "http.camera", f"the live camera needs OpenCV ({err}): pip install feeder[vision]"
        ) from None
    return None


def _image(latest: Any) -> Any:
    """The image of what ``latest_image()`` returned: an image, (image, detections), or None."""
    return latest[0] if isinstance(latest, tuple) else latest


class LiveFeed:
    """The newest status, shared by every live client and ``/api/status``: at most one
    ``status`` request reaches the daemon per :data:`STATUS_MAX_AGE_S` however many pages
    and scripts ask (a burst of requests costs the daemon one)."""

    def __init__(self, daemon: Handler) -> None:
        self.daemon = daemon
        self._lock = asyncio.Lock()
        self._status: dict[str, Any] = {}
        self._message = ""
        self._taken_s = -math.inf

    async def _refresh(self) -> None:
        async with self._lock:
            if time.monotonic() - self._taken_s >= STATUS_MAX_AGE_S:
                wall = time.time()
                self._status = await run_in_threadpool(self.daemon.handle, {"cmd": "status"})
                self._taken_s = time.monotonic()
                self._message = json.dumps(
                    {"type": "status", "time_s": wall, "status": self._status}, allow_nan=False, default=str
                )

    async def status(self) -> dict[str, Any]:
        await self._refresh()
        return self._status

    async def message(self) -> str:
        """The status as the live socket's text message (``time_s``: wall clock before it was taken)."""
        await self._refresh()
        return self._message


# -- application -----------------------------------------------------------------------
def console_app(
    daemon: Handler, token: str, settings: HttpConfig, port: int, camera: CameraFeed | None = None
) -> Starlette:
    """The console's ASGI application for a server bound at ``settings.host:port``."""
    origins = own_origins(settings.host, port, settings.origins)
    moves = RateLimit(settings.moves_per_s, settings.move_burst)
    live = LiveFeed(daemon)
    pages = {name: resources.files("feeder.web.static").joinpath(name).read_bytes() for name in STATIC}

    async def ask(request: dict[str, Any]) -> dict[str, Any]:
        return await run_in_threadpool(daemon.handle, request)

    def reply(answer: dict[str, Any]) -> JSONResponse:
        """200 for an answer (a move that ran, even when it did not end done), 409 for a refusal."""
        refused = not answer.get("ok") and "result" not in answer
        return JSONResponse(answer, status_code=409 if refused else 200)

    def rate_limited() -> None:
        wait_s = moves.take()
        if wait_s > 0:
            raise ApiError(
                429, f"too many moves: at most {settings.moves_per_s:g}/s; retry in {wait_s:.2f} s"
            )

    def endpoint(
        handler: Callable[[Request], Awaitable[Response]],
    ) -> Callable[[Request], Awaitable[Response]]:
        async def guarded(request: Request) -> Response:
            try:
                return await handler(request)
            except ApiError as err:
                headers = {"Retry-After": "1"} if err.status == 429 else None
                return error_response(err.status, err.message, headers)

        return guarded

    async def page(request: Request) -> Response:
        name = request.url.path.lstrip("/") or "console.html"
        media = "text/html" if name.endswith(".html") else "text/javascript"
        return Response(
            pages[name],
            media_type=media,
            headers={
                "Cache-Control": "no-store",
                "Content-Security-Policy": "default-src 'self'; img-src 'self' blob: data:; "
                "connect-src 'self'; style-src 'self' 'unsafe-inline'; frame-ancestors 'none'",
                "X-Content-Type-Options": "nosniff",
                "Referrer-Policy": "no-referrer",
            },
        )

    async def status(request: Request) -> Response:
        return reply(await live.status())

    async def history(request: Request) -> Response:
        text = request.query_params.get("limit", "100")
        if not text.isdigit():
            raise ApiError(400, f"limit must be a positive integer, got {text[:20]!r}")
        return reply(await ask({"cmd": "history", "limit": int(text)}))

    async def move(request: Request) -> Response:
        body = checked("move", await json_body(request))
        rate_limited()
        return reply(await ask({**body, "cmd": "move"}))

    async def calibrate(request: Request) -> Response:
        body = checked("calibrate", await json_body(request))
        rate_limited()
        return reply(await ask({**body, "cmd": "calibrate"}))

    async def stop(request: Request) -> Response:
        checked("stop", await json_body(request))
        return reply(await ask({"cmd": "stop"}))

    async def jog(request: Request) -> Response:
        body = checked("jog", await json_body(request))
        if not isinstance(body.get("axis"), str) or "steps" not in body:
            raise ApiError(400, "give axis ('x', 'y' or 'theta') and steps (signed integer)")
        rate_limited()
        current = await live.status()
        request_ = jog_request(current, body["axis"], body["steps"], body.get("part", 1))
        answer = await ask(request_)
        return reply({**answer, "jog": {k: v for k, v in request_.items() if k != "cmd"}})

    async def live_socket(ws: WebSocket) -> None:
        if not origin_allowed(ws.headers, origins):
            await ws.close(code=WS_FORBIDDEN)
            return
        await ws.accept()
        try:
            hello = json.loads(await asyncio.wait_for(ws.receive_text(), WS_AUTH_TIMEOUT_S))
        except (TimeoutError, ValueError, KeyError, WebSocketDisconnect, RuntimeError):
            hello = None
        if not isinstance(hello, dict) or not token_matches(token, str(hello.get("token"))):
            with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
                await ws.send_text(json.dumps({"type": "error", "error": "wrong token"}))
                await ws.close(code=WS_UNAUTHORIZED)
            return
        closed = asyncio.Event()

        async def drain() -> None:  # the client sends nothing more: notice when it leaves
            with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
                while (await ws.receive())["type"] != "websocket.disconnect":
                    pass
            closed.set()

        reader = asyncio.create_task(drain())
        sent_frame = 0
        deadline = time.monotonic()
        try:
            while not closed.is_set() and ws.application_state == WebSocketState.CONNECTED:
                deadline = max(deadline + LIVE_PERIOD_S, time.monotonic())  # a fixed rate, never a burst
                await ws.send_text(await live.message())
                if camera is not None and camera.jpeg is not None and camera.sequence != sent_frame:
                    sent_frame = camera.sequence
                    width, height = camera.size_px
                    await ws.send_text(json.dumps({"type": "frame", "width_px": width, "height_px": height}))
                    await ws.send_bytes(camera.jpeg)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(closed.wait(), max(0.0, deadline - time.monotonic()))
        except (WebSocketDisconnect, RuntimeError, OSError):
            pass
        finally:
            reader.cancel()

    async def not_found(request: Request, exc: Exception) -> Response:
        assert isinstance(exc, HTTPException)
        return error_response(exc.status_code, f"{request.method} {request.url.path}: {exc.detail}")

    async def internal(request: Request, exc: Exception) -> Response:
        log.error("console: %s %s failed: %r", request.method, request.url.path, exc)
        return error_response(500, f"internal error ({type(exc).__name__}); see the daemon's log")

    routes = [
        Route("/", page),
        Route("/console.js", page),
        Route("/api/status", endpoint(status)),
        Route("/api/history", endpoint(history)),
        Route("/api/move", endpoint(move), methods=["POST"]),
        Route("/api/jog", endpoint(jog), methods=["POST"]),
        Route("/api/stop", endpoint(stop), methods=["POST"]),
        Route("/api/calibrate", endpoint(calibrate), methods=["POST"]),
        WebSocketRoute("/api/live", live_socket),
    ]
    return Starlette(
        routes=routes,
        middleware=[Middleware(ApiGuard, token=token, origins=origins)],
        exception_handlers={HTTPException: not_found, Exception: internal},
    )


# -- server -----------------------------------------------------------------------------
class ConsoleServer:
    """uvicorn serving :func:`console_app` on its own thread; :meth:`stop` ends it.

    Binds ``settings.host:settings.port`` at construction (port 0: any free one), so
    a taken port is an :class:`InputError` before anything is served.
    """

    def __init__(
        self, daemon: Handler, settings: HttpConfig, token: str, camera: CameraFeed | None = None
    ) -> None:
        family = socket.AF_INET6 if ":" in settings.host else socket.AF_INET
        self._socket = socket.socket(family, socket.SOCK_STREAM)
        try:
            self._socket.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._socket.bind((settings.host, settings.port))
            self._socket.listen(128)
        except OSError as err:
            self._socket.close()
            raise InputError("--http", f"cannot listen on {settings.host}:{settings.port}: {err}") from None
        self.host = settings.host
        self.port = int(self._socket.getsockname()[1])
        self.token = token
        self.camera = camera
        app = console_app(daemon, token, settings, self.port, self.camera)
        config = uvicorn.Config(
            app,
            log_level="warning",
            access_log=False,
            lifespan="off",
            ws="websockets-sansio",
            timeout_keep_alive=5,
        )
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(
            target=self._server.run, kwargs={"sockets": [self._socket]}, name="console-http", daemon=True
        )

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    @property
    def token_url(self) -> str:
        """The page's address with the token in the fragment (never sent to the server)."""
        return f"{self.url}#token={self.token}"

    def start(self, timeout_s: float = 10.0) -> None:
        self._thread.start()
        deadline = time.monotonic() + timeout_s
        while not self._server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise InputError("--http", f"the console did not start on {self.url}")
            time.sleep(0.01)

    def stop(self) -> None:
        self._server.should_exit = True
        self._thread.join(timeout=5.0)
        self._socket.close()
        if self.camera is not None:
            self.camera.close()


def start_console(
    daemon: Handler, settings: HttpConfig, state_dir: Path, camera: str | None = None
) -> ConsoleServer:
    """A new token in ``state_dir``, and the console serving with it; ``camera``: the live
    view's camera spec when the configuration names none (see :func:`camera_feed`)."""
    feed = camera_feed(settings.camera or camera, daemon)
    try:
        server = ConsoleServer(daemon, settings, new_token(state_dir), feed)
    except InputError:
        if feed is not None:
            feed.close()
        raise
    try:
        server.start()
    except InputError:
        server.stop()
        raise
    return server
