"""Endpoints: the console on TCP or a pty, and the camera's frame stream on TCP.

Servers bind to 127.0.0.1 only.  Each console connection gets its own
:class:`~firmware_sim.console.ConsoleSession`.  The pty behaves like a serial
port with a modem-control line: a new session (login state, echo) starts each
time a program opens the pty's device path, and ends when it closes it (the
pty master sees the hang-up), as a real unit sees DTR.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import socketserver
import termios
import threading
import time
import tty
from collections.abc import Callable

from firmware_sim.console import ConsoleSession

LOCALHOST = "127.0.0.1"
MAX_CONSOLE_CLIENTS = 32
HANGUP_POLL_S = 0.005

SessionFactory = Callable[[], ConsoleSession]


def check_local(host: str) -> None:
    """Refuse any bind address but 127.0.0.1 / localhost."""
    if host not in (LOCALHOST, "localhost"):
        raise ValueError(f"refusing to bind {host!r}: only {LOCALHOST} is allowed")


class _ConsoleHandler(socketserver.BaseRequestHandler):
    server: _ConsoleTcpServer

    def handle(self) -> None:
        sock: socket.socket = self.request
        with self.server.count_lock:
            full = self.server.clients >= MAX_CONSOLE_CLIENTS
            if not full:
                self.server.clients += 1
        if full:
            return
        try:
            session = self.server.session_factory()
            sock.sendall(session.greeting())
            while not session.closed:
                data = sock.recv(4096)
                if not data:
                    break
                reply = session.feed(data)
                if reply:
                    sock.sendall(reply)
        except OSError:
            pass  # the client went away mid-line or mid-reply
        finally:
            with self.server.count_lock:
                self.server.clients -= 1


class _ConsoleTcpServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 2 * MAX_CONSOLE_CLIENTS

    def __init__(self, address: tuple[str, int], session_factory: SessionFactory) -> None:
        self.session_factory = session_factory
        self.count_lock = threading.Lock()
        self.clients = 0
        super().__init__(address, _ConsoleHandler)


class TcpConsoleServer:
    """The console on ``host:port`` (port 0 picks a free one; see :attr:`port`)."""

    def __init__(self, host: str, port: int, session_factory: SessionFactory) -> None:
        check_local(host)
        self._server = _ConsoleTcpServer((host, port), session_factory)
        self.host, self.port = self._server.socket.getsockname()[:2]
        self._thread = threading.Thread(target=self._server.serve_forever,
                                        kwargs={"poll_interval": 0.1},
                                        name="console-tcp", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"socket://{self.host}:{self.port}"

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()


class PtyConsole:
    """The console on a pseudo-terminal; :attr:`path` is the device to open."""

    def __init__(self, session_factory: SessionFactory) -> None:
        self._factory = session_factory
        self._master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        os.close(slave)  # nobody has it open → the master sees a hang-up
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="console-pty", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        poller = select.poll()
        poller.register(self._master, select.POLLIN)
        session: ConsoleSession | None = None
        while not self._stop.is_set():
            timeout_ms = 100 if session is not None else HANGUP_POLL_S * 1000
            event = dict(poller.poll(timeout_ms)).get(self._master, 0)
            if event & select.POLLHUP:
                if session is not None:  # the program closed the pty: drop unread replies
                    with contextlib.suppress(termios.error):
                        termios.tcflush(self._master, termios.TCOFLUSH)
                session = None
                time.sleep(HANGUP_POLL_S)
                continue
            if session is None:  # no hang-up any more: a program opened the pty
                session = self._factory()
                if not session.logged_in:
                    self._write(session.greeting())
            if event & select.POLLIN:
                try:
                    data = os.read(self._master, 4096)
                except OSError:
                    session = None
                    continue
                reply = session.feed(data)
                if reply and not self._write(reply):
                    session = None
                if session is not None and session.closed:
                    session = None

    def _write(self, data: bytes) -> bool:
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self._master, view):]
        except OSError:
            return False
        return True

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        os.close(self._master)


class LineBroadcastServer:
    """Sends every published line to every connected TCP client (the camera stream).

    A client that does not keep up (its socket buffer is full) is dropped.
    """

    def __init__(self, host: str, port: int) -> None:
        check_local(host)
        self._listener = socket.create_server((host, port))
        self.host, self.port = self._listener.getsockname()[:2]
        self._clients: list[socket.socket] = []
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._accept, name="sensor-accept", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"socket://{self.host}:{self.port}"

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self._listener.accept()
            except OSError:
                return
            client.setblocking(False)
            with self._lock:
                self._clients.append(client)

    def publish(self, line: bytes) -> None:
        with self._lock:
            for client in list(self._clients):
                try:
                    sent = client.send(line)
                except (BlockingIOError, OSError):
                    sent = -1
                if sent != len(line):
                    self._clients.remove(client)
                    client.close()

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._listener.shutdown(socket.SHUT_RDWR)  # wakes the accept() in its thread
        self._listener.close()
        with self._lock:
            for client in self._clients:
                client.close()
            self._clients.clear()
