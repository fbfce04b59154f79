"""Serving the console: uvicorn on its own thread in the daemon's process (never the tick's),
with a fresh token at each start; its event loop stands back while the tick is due.

No client can take the daemon's descriptors: at most :func:`connection_cap` connections are
served at once (a newcomer beyond is answered 503 and closed), and a connection that has not
sent a whole request within :data:`REQUEST_TIMEOUT_S` of the server waiting for one is closed
(:class:`GuardedH11Protocol`).  uvicorn leaves the daemon's logging as it is: its warnings and
errors go to the daemon's log, its access log nowhere.
"""

from __future__ import annotations

import asyncio
import functools
import json
import logging
import resource
import socket
import threading
import time
from pathlib import Path
from typing import Any

import h11
import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from feeder.daemon.config import HttpConfig
from feeder.daemon.log_throttle import LogThrottle
from feeder.daemon.quiet_window import quiet_event_loop
from feeder.errors import InputError
from feeder.web.app import Handler, console_app
from feeder.web.camera import CameraFeed, camera_feed
from feeder.web.listener import LISTEN_BACKLOG, listen
from feeder.web.security import new_token

log = logging.getLogger(__name__)

MAX_CONNECTIONS = 256
"""HTTP and WebSocket connections served at once (45 waiting moves, a status and a stop take
47; a page takes its WebSocket and a few requests), unless the descriptor limit is lower:
:func:`connection_cap`."""
MIN_CONNECTIONS = 16
"""The fewest connections served, however low the descriptor limit."""
REQUEST_TIMEOUT_S = 5.0
"""How long a connection has to send a whole request (line, headers and body), from its
connection or the end of its last response (uvicorn has no such limit: an idle connection,
or one sending a header byte every 2 s, stayed open)."""


def connection_cap() -> int:
    """The most connections the console serves at once: :data:`MAX_CONNECTIONS`, or a quarter of
    the process's open-file limit (``ulimit -n``) when that is lower, so that the amplifier link,
    the camera, the state files and the control socket's clients keep the rest."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return MAX_CONNECTIONS
    return max(MIN_CONNECTIONS, min(MAX_CONNECTIONS, soft // 4))


def busy_reply(cap: int) -> bytes:
    """The answer to a connection beyond ``cap``, sent as it connects."""
    body = json.dumps({"ok": False, "error": f"too many connections (max {cap})"}).encode()
    return (
        b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\nretry-after: 1\r\n"
        b"connection: close\r\ncontent-length: " + str(len(body)).encode() + b"\r\n\r\n" + body
    )


_refusals = LogThrottle(log)


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol that refuses a connection beyond :func:`connection_cap` and closes
    one whose request is not whole within :data:`REQUEST_TIMEOUT_S`."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        cap = connection_cap()
        if len(self.connections) > cap:  # this one included
            _refusals.warning("console: refused a connection beyond %d", cap)
            transport.write(busy_reply(cap))
            transport.close()
            return
        self._await_request()

    def handle_events(self) -> None:
        super().handle_events()
        if self.conn.their_state not in (h11.IDLE, h11.SEND_BODY):
            self._cancel_deadline()  # the request is whole (answered, however long that takes)

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing():
            self._await_request()

    def handle_websocket_upgrade(self, event: h11.Request) -> None:
        self._cancel_deadline()  # the WebSocket's own protocol takes the connection over
        super().handle_websocket_upgrade(event)

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_deadline()
        super().connection_lost(exc)

    def _await_request(self) -> None:
        self._cancel_deadline()
        self._deadline = self.loop.call_later(REQUEST_TIMEOUT_S, self._request_overdue)

    def _cancel_deadline(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _request_overdue(self) -> None:
        self._deadline = None
        if self.conn.their_state in (h11.IDLE, h11.SEND_BODY) and not self.transport.is_closing():
            log.debug("console: closed a connection without a whole request after %g s", REQUEST_TIMEOUT_S)
            self.transport.close()


class ConsoleServer:
    """uvicorn serving :func:`console_app` on its own thread; :meth:`stop` ends it.

    Serves ``listener`` (:func:`~feeder.web.listener.listen`, which ``feeder daemon`` calls
    before it starts anything), or binds ``settings.host:settings.port`` at construction
    (port 0: any free one): a taken port is an :class:`InputError` before anything is served.
    """

    def __init__(
        self,
        daemon: Handler,
        settings: HttpConfig,
        token: str,
        camera: CameraFeed | None = None,
        listener: socket.socket | None = None,
    ) -> None:
        self._socket = listener if listener is not None else listen(settings.host, settings.port)
        self.host = settings.host
        self.port = int(self._socket.getsockname()[1])
        self.token = token
        self.camera = camera
        app = console_app(daemon, token, settings, self.port, self.camera)
        self._close_app = app.state.close
        config = uvicorn.Config(
            app,
            http=GuardedH11Protocol,
            log_config=None,  # its dictConfig closed the daemon's handlers (daemon.log reopened)
            log_level="warning",
            access_log=False,
            lifespan="off",
            ws="websockets-sansio",
            timeout_keep_alive=5,
            backlog=LISTEN_BACKLOG,
        )
        self._server = uvicorn.Server(config)
        self._loop_factory = functools.partial(quiet_event_loop, daemon.quiet)
        self._thread = threading.Thread(target=self._serve, name="console-http", daemon=True)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    @property
    def token_url(self) -> str:
        """The page's address with the token in the fragment (never sent to the server)."""
        return f"{self.url}#token={self.token}"

    def _serve(self) -> None:
        with asyncio.Runner(loop_factory=self._loop_factory) as runner:
            runner.run(self._server.serve(sockets=[self._socket]))

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
        self._close_app()
        if self.camera is not None:
            self.camera.close()


def start_console(
    daemon: Handler,
    settings: HttpConfig,
    state_dir: Path,
    camera: str | None = None,
    listener: socket.socket | None = None,
) -> ConsoleServer:
    """A new token in ``state_dir``, and the console serving with it (on ``listener`` when bound
    already); ``camera``: the live view's camera spec when the configuration names none (see
    :func:`camera_feed`)."""
    feed = camera_feed(settings.camera or camera, daemon)
    try:
        server = ConsoleServer(daemon, settings, new_token(state_dir), feed, listener)
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
