"""Serving the console: uvicorn on its own thread in the daemon's process (never the tick's),
with a fresh token at each start; its event loop stands back while the tick is due."""

from __future__ import annotations

import asyncio
import functools
import socket
import threading
import time
from pathlib import Path

import uvicorn

from feeder.daemon.config import HttpConfig
from feeder.daemon.quiet_window import quiet_event_loop
from feeder.errors import InputError
from feeder.web.app import Handler, console_app
from feeder.web.camera import CameraFeed, camera_feed
from feeder.web.security import new_token


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
        self._close_app = app.state.close
        config = uvicorn.Config(
            app,
            log_level="warning",
            access_log=False,
            lifespan="off",
            ws="websockets-sansio",
            timeout_keep_alive=5,
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
