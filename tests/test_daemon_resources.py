"""The daemon out of descriptors: ``stop`` still reaches it (docs/daemon.md, *Control
interface*).  An audit under ``ulimit -n 1024`` opened 1100 idle connections to the HTTP
console and 10 to the control socket; the socket's accepting thread ended at its first EMFILE,
uvicorn's logging set-up had closed daemon.log (whose reopening then killed the console's
thread), and ``feeder stop`` got no answer.

- the control socket keeps accepting through EMFILE, and closes an idle client for a ``stop``
  (a child process with a low descriptor limit);
- the console caps its connections and closes one that sends no whole request in time;
- the console leaves the daemon's logging as it was.
"""

from __future__ import annotations

import contextlib
import http.client
import json
import logging
import resource
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_socket_server_limits import Line, ScriptedDaemon, Served

from feeder.cli.daemon import setup_logging
from feeder.daemon import socket_server
from feeder.daemon.config import HttpConfig
from feeder.daemon.quiet_window import QuietWindow
from feeder.web import server as web_server

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.timeout(60)
STOPPED = {"ok": True, "stopped": True, "dequeued": 0}

CHILD = """
import os, resource, sys, threading
from pathlib import Path
from feeder.daemon import socket_server

socket_server.DOORWAY_TIMEOUT_S = 0.3  # an idle client gives way sooner under exhaustion

def handle(request, hung_up):
    if request.get("cmd") == "stop":
        return {"ok": True, "stopped": True, "dequeued": 0}
    return {"ok": True, "state": "idle"}

server = socket_server.SocketServer(Path(sys.argv[1]), handle)
resource.setrlimit(resource.RLIMIT_NOFILE, (64, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
held = []
print("ready", flush=True)
for line in sys.stdin:
    if line.strip() == "exhaust":
        try:
            while True:
                held.append(os.open(os.devnull, os.O_RDONLY))
        except OSError:
            pass
        print("exhausted", flush=True)
    elif line.strip() == "free":
        for fd in held:
            os.close(fd)
        held.clear()
        print("freed", flush=True)
"""


class Child:
    """A socket server in a process of its own whose descriptors the test can use up."""

    def __init__(self, base: Path) -> None:
        self.path = base / "run" / "f.sock"
        self.process = subprocess.Popen(
            [sys.executable, "-c", CHILD, str(self.path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        self.expect("ready")

    def tell(self, command: str, answer: str) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()
        self.expect(answer)

    def expect(self, answer: str) -> None:
        assert self.process.stdout is not None
        assert self.process.stdout.readline().strip() == answer

    def stderr(self) -> str:
        self.process.kill()
        _, err = self.process.communicate(timeout=10)
        return err


@pytest.fixture
def child(short_dir: Path) -> Iterator[Child]:
    running = Child(short_dir)
    yield running
    if running.process.poll() is None:
        running.process.kill()
        running.process.communicate(timeout=10)


def test_the_socket_keeps_accepting_through_a_lack_of_descriptors(child: Child) -> None:
    """A ``stop`` sent while the process has no descriptor left is answered once one frees; the
    failures are logged once, not once per attempt (every 0.1 s)."""
    child.tell("exhaust", "exhausted")
    line = Line(child.path)  # the kernel queues it; the server cannot accept it yet
    line.send({"cmd": "stop"})
    time.sleep(1.0)
    child.tell("free", "freed")
    assert line.read(timeout_s=5.0) == STOPPED
    assert Line(child.path).ask({"cmd": "status"}) == {"ok": True, "state": "idle"}
    log = child.stderr()
    assert log.count("cannot accept a control connection") == 1, log
    assert "Too many open files" in log


def test_an_idle_client_gives_way_to_a_stop_when_descriptors_run_out(child: Child) -> None:
    idle = Line(child.path)
    assert idle.ask({"cmd": "status"}) == {"ok": True, "state": "idle"}
    time.sleep(0.4)  # silent longer than the child's DOORWAY_TIMEOUT_S
    child.tell("exhaust", "exhausted")
    stopper = Line(child.path)
    assert stopper.ask({"cmd": "stop"}, timeout_s=5.0) == STOPPED  # the descriptors are still held
    assert idle.read() is None  # closed for it


def test_a_client_thread_that_cannot_start_does_not_end_the_accepting(
    short_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    failed: list[str] = []

    class OnceFailing(threading.Thread):
        def start(self) -> None:
            if self.name == "client" and not failed:
                failed.append(self.name)
                raise RuntimeError("can't start new thread")
            super().start()

    served = Served(short_dir, ScriptedDaemon())
    try:
        monkeypatch.setattr(socket_server.threading, "Thread", OnceFailing)
        assert served.connect().read() is None  # closed: no thread to serve it
        monkeypatch.undo()
        assert served.connect().ask({"cmd": "stop"}) == STOPPED
        assert failed == ["client"]
    finally:
        served.close()


# -- the HTTP console --------------------------------------------------------------------------


class _Handler:
    """The daemon as the console sees it: a move waits ``move_s``."""

    def __init__(self, move_s: float = 0.0) -> None:
        self.move_s = move_s
        self.quiet = QuietWindow()

    def handle(self, request: Any) -> dict[str, Any]:
        if request.get("cmd") == "move":
            time.sleep(self.move_s)
            return {"ok": True, "result": {"status": "done"}}
        if request.get("cmd") == "stop":
            return STOPPED
        return {"ok": True, "state": "idle"}


TOKEN = "t" * 43


@pytest.fixture
def console() -> Iterator[web_server.ConsoleServer]:
    server = web_server.ConsoleServer(_Handler(move_s=1.5), HttpConfig(port=0), TOKEN)
    server.start()
    yield server
    server.stop()


def _call(port: int, method: str, path: str, body: Any = None) -> tuple[int, dict[str, Any]]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        data = None if body is None else json.dumps(body).encode()
        conn.request(method, path, body=data, headers={"Authorization": f"Bearer {TOKEN}"})
        response = conn.getresponse()
        return response.status, json.loads(response.read())
    finally:
        conn.close()


def _closed_within(sock: socket.socket, timeout_s: float) -> float:
    """How long until the server closed ``sock`` (reading what it sent); fails after ``timeout_s``."""
    started = time.monotonic()
    sock.settimeout(timeout_s)
    with contextlib.suppress(ConnectionResetError):  # closed with our bytes unread
        while sock.recv(4096):
            pass
    return time.monotonic() - started


def test_the_console_refuses_connections_beyond_its_cap(
    console: web_server.ConsoleServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(web_server, "connection_cap", lambda: 4)
    held = [socket.create_connection(("127.0.0.1", console.port)) for _ in range(4)]
    try:
        time.sleep(0.2)
        extra = socket.create_connection(("127.0.0.1", console.port))
        extra.settimeout(5.0)
        answer = extra.recv(4096)
        assert answer.startswith(b"HTTP/1.1 503 ") and b"retry-after: 1" in answer
        assert answer.endswith(b'{"ok": false, "error": "too many connections (max 4)"}')
        assert extra.recv(4096) == b""  # and closed
        extra.close()
        held.pop().close()
        time.sleep(0.2)
        assert _call(console.port, "POST", "/api/stop") == (200, STOPPED)
    finally:
        for sock in held:
            sock.close()


@pytest.mark.parametrize(
    ("soft_limit", "cap"),
    [(1024, 256), (resource.RLIM_INFINITY, 256), (400, 100), (256, 64), (40, 16)],
)
def test_the_console_cap_leaves_most_descriptors_to_the_daemon(
    soft_limit: int, cap: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A quarter of ``ulimit -n`` when that is below 256 connections, never fewer than 16."""
    monkeypatch.setattr(resource, "getrlimit", lambda _which: (soft_limit, resource.RLIM_INFINITY))
    assert web_server.connection_cap() == cap


def test_the_console_closes_connections_that_send_no_whole_request(
    console: web_server.ConsoleServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An idle connection, one sending a header byte every 0.2 s and one whose body stalls are
    closed after the request timeout; a move that takes longer to answer is not cut."""
    monkeypatch.setattr(web_server, "REQUEST_TIMEOUT_S", 0.5, raising=False)
    idle = socket.create_connection(("127.0.0.1", console.port))
    dribbling = socket.create_connection(("127.0.0.1", console.port))
    stalled = socket.create_connection(("127.0.0.1", console.port))
    stalled.sendall(
        f"POST /api/move HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {TOKEN}\r\n"
        "Content-Length: 100\r\n\r\n{".encode()
    )
    header = b"GET /api/status HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * 40
    started = time.monotonic()
    try:
        for byte in header:
            dribbling.sendall(bytes([byte]))
            time.sleep(0.2)
            if time.monotonic() - started > 2.0:
                break
    except (BrokenPipeError, ConnectionResetError):
        pass  # closed meanwhile
    assert _closed_within(dribbling, 1.0) < 1.0
    assert _closed_within(idle, 1.0) < 1.0
    assert _closed_within(stalled, 1.0) < 1.0
    assert time.monotonic() - started < 3.0
    status, reply = _call(console.port, "POST", "/api/move", {"target_m": 1e-4})  # answered after 1.5 s
    assert (status, reply) == (200, {"ok": True, "result": {"status": "done"}})


def test_a_kept_alive_connection_must_send_its_next_request_whole(
    console: web_server.ConsoleServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    """uvicorn's keep-alive timer stops at the next request's first byte."""
    monkeypatch.setattr(web_server, "REQUEST_TIMEOUT_S", 0.5, raising=False)
    conn = http.client.HTTPConnection("127.0.0.1", console.port, timeout=10)
    conn.request("GET", "/api/status", headers={"Authorization": f"Bearer {TOKEN}"})
    assert conn.getresponse().read()
    assert conn.sock is not None
    conn.sock.sendall(b"GET /api/status HTTP/1.1\r\n")  # and no more
    assert _closed_within(conn.sock, 2.0) < 1.0
    conn.close()


@pytest.fixture
def daemon_logging(tmp_path: Path) -> Iterator[Path]:
    """The daemon's logging set up as ``feeder daemon`` does; the test process' restored after."""
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    log_file = tmp_path / "state" / "daemon.log"
    setup_logging("info", log_file)
    yield log_file
    for handler in root.handlers:
        if handler not in handlers:
            handler.close()
    root.handlers[:], root.level = handlers, level


def test_the_console_leaves_the_daemons_log_open(daemon_logging: Path) -> None:
    """uvicorn's default logging set-up (dictConfig) closed every handler: daemon.log was
    reopened by the next record, which with no descriptor left raised in the console's thread.
    Its own warnings reached only stderr."""
    root = logging.getLogger()
    before = root.handlers[:]
    server = web_server.ConsoleServer(_Handler(), HttpConfig(port=0), TOKEN)
    server.start()
    try:
        assert root.handlers == before
        files = [h for h in root.handlers if isinstance(h, logging.FileHandler)]
        assert files and all(h.stream is not None and not h.stream.closed for h in files)
        with socket.create_connection(("127.0.0.1", server.port)) as garbage:
            garbage.sendall(b"NOT HTTP\r\n\r\n")
            _closed_within(garbage, 5.0)
        assert _call(server.port, "GET", "/api/status")[0] == 200
    finally:
        server.stop()
    logging.getLogger("feeder.daemon.service").info("still logging")
    for handler in root.handlers:
        handler.flush()
    text = daemon_logging.read_text()
    assert "still logging" in text
    assert "WARNING uvicorn.error: Invalid HTTP request received." in text  # uvicorn's own, kept
    assert "GET /api/status" not in text  # no access log
