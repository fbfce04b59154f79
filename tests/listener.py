"""A listening socket for the tests' helper servers, whose accepting thread ends on close."""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Callable


class Listener:
    """Accepts connections on ``server`` in a thread of its own and hands each to ``on_connect``.

    close() shuts the socket down before closing it: on Linux closing a listening
    socket does not wake a thread blocked in accept(), shutting it down does.
    """

    def __init__(self, server: socket.socket, on_connect: Callable[[socket.socket], None]) -> None:
        self.server = server
        self._on_connect = on_connect
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    @property
    def port(self) -> int:
        return int(self.server.getsockname()[1])

    def _accept(self) -> None:
        with contextlib.suppress(OSError):
            while True:
                self._on_connect(self.server.accept()[0])

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.server.shutdown(socket.SHUT_RDWR)
        self.server.close()
        self._thread.join(timeout=1.0)
