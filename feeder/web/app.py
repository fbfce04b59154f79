"""The console's ASGI application (docs/console.md): ``GET /`` serves the page (static HTML
and script, no data).  The JSON API mirrors the socket's commands and answers by calling the
daemon's own request handler (:meth:`~feeder.daemon.service.Daemon.handle`), so the page, the
CLI and scripts share one vocabulary:

| route | request |
|---|---|
| ``GET /api/status`` | ``{"cmd": "status"}`` (shared by the requests within 25 ms) |
| ``GET /api/history?limit=N`` | ``{"cmd": "history", "limit": N}`` |
| ``POST /api/move`` | ``{"cmd": "move", ...body}`` (``target_m``, ``by_m``, or ``x_m``, ``y_m``,
  ``angle_rad``, ``part``) |
| ``POST /api/jog`` | ``{"axis", "steps"}``: a relative move by ``steps`` learned steps of one axis |
| ``POST /api/stop`` | ``{"cmd": "stop"}`` |
| ``POST /api/calibrate`` | ``{"cmd": "calibrate", ...body}`` |
| ``POST /api/calibrate_camera`` | ``{"cmd": "calibrate_camera", ...body}`` (``volts``,
  ``stack_gain_m_per_v``, ``increment_v``, ``frames``, ``save``): answered when the plate moves
  end (a closed page does not stop them: STOP does) |
| ``POST /api/release`` | ``{"cmd": "release", ...body}`` (``part``; none: every held part) |
| ``WS /api/live`` | pushes each new status (JSON text, ``time_s`` = wall clock of the snapshot),
  one per :data:`~feeder.web.live_feed.LIVE_PERIOD_S`, and the newest camera frame (binary JPEG)
  when there is a camera |

Who may call it: :mod:`feeder.web.security`.  Bad requests get ``{"ok": false, "error": ...}``
with a 4xx code; a refusal by the daemon is 409; more than
:data:`~feeder.web.lanes.MAX_WAITING_MOVES` moves waiting at once, 503.  Where each call into the
daemon runs (never where a waiting move can keep a stop out): :mod:`feeder.web.lanes`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Awaitable, Callable
from importlib import resources
from typing import Any, Protocol

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect, WebSocketState

from feeder.daemon.config import HttpConfig
from feeder.daemon.quiet_window import QuietWindow
from feeder.web.camera import CameraFeed
from feeder.web.lanes import MoveLane, UrgentLane
from feeder.web.live_feed import LiveFeed
from feeder.web.requests import ApiError, checked, error_response, jog_request, json_body
from feeder.web.security import ApiGuard, RateLimit, own_origins, websocket_admitted

log = logging.getLogger(__name__)

MAX_LIMIT_DIGITS = 9
"""``/api/history?limit=``: longer is refused (400) before the daemon sees it."""
STATIC = ("console.html", "plate_view.js", "console.js")
"""The page's files, package data of :mod:`feeder.web.static`."""


class Handler(Protocol):
    """What the console needs of the daemon: its request handler, and the window in which the
    console's threads stand back for the tick (:mod:`feeder.daemon.quiet_window`)."""

    def handle(self, request: Any) -> dict[str, Any]: ...

    @property
    def quiet(self) -> QuietWindow: ...


def console_app(
    daemon: Handler, token: str, settings: HttpConfig, port: int, camera: CameraFeed | None = None
) -> Starlette:
    """The console's ASGI application for a server bound at ``settings.host:port``."""
    origins = own_origins(settings.host, port, settings.origins)
    moves = RateLimit(settings.moves_per_s, settings.move_burst)
    urgent = UrgentLane()  # stop and status
    waiting = MoveLane()  # moves, jogs, calibrations (the camera's too)
    live = LiveFeed(daemon.handle, urgent)
    pages = {name: resources.files("feeder.web.static").joinpath(name).read_bytes() for name in STATIC}

    async def ask(request: dict[str, Any]) -> dict[str, Any]:
        """A request that neither waits for a move nor must pass one (history)."""
        return await run_in_threadpool(daemon.handle, request)

    async def ask_move(request: dict[str, Any]) -> dict[str, Any]:
        return await waiting.run(daemon.handle, request)

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
                headers = {"Retry-After": "1"} if err.status in (429, 503) else None
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
        # ASCII digits only (str.isdigit takes "²", which int() refuses), and few of them (int()
        # refuses more than 4300); the daemon checks the range
        if not (text.isascii() and text.isdigit() and len(text) <= MAX_LIMIT_DIGITS):
            raise ApiError(400, f"limit must be a positive integer, got {text[:20]!r}")
        return reply(await ask({"cmd": "history", "limit": int(text)}))

    async def move(request: Request) -> Response:
        body = checked("move", await json_body(request))
        rate_limited()
        return reply(await ask_move({**body, "cmd": "move"}))

    async def calibrate(request: Request) -> Response:
        body = checked("calibrate", await json_body(request))
        rate_limited()
        return reply(await ask_move({**body, "cmd": "calibrate"}))

    async def calibrate_camera(request: Request) -> Response:
        body = checked("calibrate_camera", await json_body(request))
        rate_limited()
        return reply(await ask_move({**body, "cmd": "calibrate_camera"}))

    async def release(request: Request) -> Response:
        body = checked("release", await json_body(request))
        return reply(await ask({**body, "cmd": "release"}))

    async def stop(request: Request) -> Response:
        # the body is not read: a stop acts whatever it carries (nothing may keep it from the daemon)
        return reply(await urgent.run(daemon.handle, {"cmd": "stop"}))

    async def jog(request: Request) -> Response:
        body = checked("jog", await json_body(request))
        if not isinstance(body.get("axis"), str) or "steps" not in body:
            raise ApiError(400, "give axis ('x', 'y' or 'theta') and steps (signed integer)")
        rate_limited()
        current = await live.status()
        request_ = jog_request(current, body["axis"], body["steps"], body.get("part", 1))
        answer = await ask_move(request_)
        return reply({**answer, "jog": {k: v for k, v in request_.items() if k != "cmd"}})

    async def live_socket(ws: WebSocket) -> None:
        if not await websocket_admitted(ws, token, origins):
            return

        async def drain() -> None:  # the client sends nothing more: ends when it leaves
            with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
                while (await ws.receive())["type"] != "websocket.disconnect":
                    pass

        reader = asyncio.create_task(drain())
        sent_frame = 0
        watching = camera.watching() if camera is not None else contextlib.nullcontext()
        try:
            async with live.watched() as seen:
                with watching:  # the camera's frames are encoded only while a page watches them
                    while ws.application_state == WebSocketState.CONNECTED:
                        news = await live.next_message(seen, unless=reader)
                        if news is None:
                            break
                        seen, message = news
                        await ws.send_text(message)
                        jpeg = None if camera is None else camera.jpeg
                        if camera is not None and jpeg is not None and camera.sequence != sent_frame:
                            sent_frame = camera.sequence
                            width, height = camera.size_px
                            await ws.send_text(
                                json.dumps({"type": "frame", "width_px": width, "height_px": height})
                            )
                            await ws.send_bytes(jpeg)
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
        Route("/plate_view.js", page),
        Route("/console.js", page),
        Route("/api/status", endpoint(status)),
        Route("/api/history", endpoint(history)),
        Route("/api/move", endpoint(move), methods=["POST"]),
        Route("/api/jog", endpoint(jog), methods=["POST"]),
        Route("/api/stop", endpoint(stop), methods=["POST"]),
        Route("/api/calibrate", endpoint(calibrate), methods=["POST"]),
        Route("/api/calibrate_camera", endpoint(calibrate_camera), methods=["POST"]),
        Route("/api/release", endpoint(release), methods=["POST"]),
        WebSocketRoute("/api/live", live_socket),
    ]
    app = Starlette(
        routes=routes,
        middleware=[Middleware(ApiGuard, token=token, origins=origins)],
        exception_handlers={HTTPException: not_found, Exception: internal},
    )
    app.state.close = urgent.close  # the server's stop ends the stop-and-status threads
    return app
