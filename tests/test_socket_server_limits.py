"""The Unix socket's limits (feeder/daemon/socket_server.py): no number of silent, half-written
or waiting clients keeps ``stop`` and ``status`` from the daemon, and a client waiting for its
move or silent while there is room is never cut.  A scripted handler stands in for the daemon:
its moves wait until a ``stop``."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from feeder.daemon import socket_server
from feeder.daemon.client import Client
from feeder.daemon.socket_server import SocketServer

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.timeout(60)
REFUSAL = f"too many clients (max {socket_server.MAX_CLIENTS})"


class ScriptedDaemon:
    """``handle`` as the daemon's: a move waits until a stop (or ``move_s``)."""

    def __init__(self, move_s: float = 30.0) -> None:
        self.move_s = move_s
        self.stopped = threading.Event()
        self.hung_up = threading.Event()
        self.waiting = 0
        self._lock = threading.Lock()

    def handle(self, request: Any, hung_up: Callable[[], bool]) -> dict[str, Any]:
        cmd = request.get("cmd") if isinstance(request, dict) else None
        if cmd == "watch":  # as a camera calibration: until a stop or its client's hang-up
            while not self.stopped.wait(0.01):
                if hung_up():
                    self.hung_up.set()
                    break
            return {"ok": True, "hung_up": self.hung_up.is_set()}
        if cmd == "stop":
            self.stopped.set()
            return {"ok": True, "stopped": True, "dequeued": 0}
        if cmd == "status":
            return {"ok": True, "state": "moving", "waiting": self.waiting}
        if cmd == "move":
            with self._lock:
                self.waiting += 1
            self.stopped.wait(self.move_s)
            with self._lock:
                self.waiting -= 1
            return {"ok": True, "result": {"status": "stopped" if self.stopped.is_set() else "done"}}
        if cmd == "big":
            return {"ok": True, "pad": "x" * 4_000_000}
        if cmd == "bug":  # a handler's programming error
            return {"ok": True, "missing": {}["key"]}
        return {"ok": False, "error": f"unknown cmd {cmd!r}"}


class Line:
    """A raw connection: send request objects, read reply lines."""

    def __init__(self, path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(str(path))
        self.buffer = b""

    def send(self, obj: Any) -> None:
        self.sock.sendall(json.dumps(obj).encode() + b"\n")

    def read(self, timeout_s: float = 5.0) -> dict[str, Any] | None:
        """The next reply; None at end of stream; TimeoutError when none comes in ``timeout_s``."""
        self.sock.settimeout(timeout_s)
        while b"\n" not in self.buffer:
            chunk = self.sock.recv(1 << 20)
            if not chunk:
                return None
            self.buffer += chunk
        line, self.buffer = self.buffer.split(b"\n", 1)
        reply: dict[str, Any] = json.loads(line)
        return reply

    def ask(self, obj: Any, timeout_s: float = 5.0) -> dict[str, Any] | None:
        self.send(obj)
        return self.read(timeout_s)

    def close(self) -> None:
        self.sock.close()


class Served:
    def __init__(self, base: Path, daemon: ScriptedDaemon) -> None:
        self.daemon = daemon
        self.path = base / "run" / "f.sock"
        self.server = SocketServer(self.path, daemon.handle)
        self.lines: list[Line] = []

    def connect(self) -> Line:
        line = Line(self.path)
        self.lines.append(line)
        return line

    def fill(self, count: int) -> list[Line]:
        """``count`` connections that send nothing, each served (status answered) first, so
        that they are known to hold their slots."""
        held = [self.connect() for _ in range(count)]
        for line in held:
            assert line.ask({"cmd": "status"}) is not None
        return held

    def close(self) -> None:
        self.daemon.stopped.set()
        for line in self.lines:
            line.close()
        self.server.close()


@pytest.fixture
def served(short_dir: Path) -> Iterator[Served]:
    running = Served(short_dir, ScriptedDaemon())
    yield running
    running.close()


def wait_until(condition: Any, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_stop_and_status_are_answered_while_silent_connections_hold_every_slot(served: Served) -> None:
    served.fill(socket_server.MAX_CLIENTS)
    late = served.connect()
    assert late.ask({"cmd": "status"}) == {"ok": True, "state": "moving", "waiting": 0}
    assert late.ask({"cmd": "status"}) is not None  # the connection goes on serving them
    with Client(served.path, timeout_s=5.0) as client:
        assert client.stop().stopped is True
    other = served.connect()
    assert other.ask({"cmd": "move", "target_m": 1e-4}) == {"ok": False, "error": REFUSAL}
    assert other.read() is None  # and closed


def test_feeder_stop_reaches_the_daemon_while_every_slot_waits_for_a_move(served: Served) -> None:
    movers = [served.connect() for _ in range(socket_server.MAX_CLIENTS)]
    for line in movers:
        line.send({"cmd": "move", "target_m": 4.5e-3, "queue": True})
    wait_until(lambda: served.daemon.waiting == socket_server.MAX_CLIENTS)
    started = time.monotonic()
    cli = subprocess.run(
        [sys.executable, "-m", "feeder", "stop", "--socket", str(served.path), "--timeout", "5"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=30,
    )
    assert cli.returncode == 0, (cli.stdout, cli.stderr)
    assert time.monotonic() - started < 10
    for line in movers:  # the stop ended every waiting move
        assert line.read() == {"ok": True, "result": {"status": "stopped"}}


def test_a_request_line_left_half_written_is_closed_after_the_idle_timeout(
    served: Served, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(socket_server, "IDLE_TIMEOUT_S", 0.3)
    slow = served.connect()
    slow.sock.sendall(b'{"cmd": "sta')
    started = time.monotonic()
    reply = slow.read(timeout_s=3.0)
    assert reply is not None and "incomplete after 0.3 s" in reply["error"]
    assert slow.read() is None
    assert 0.25 < time.monotonic() - started < 2.0
    # a line dribbled a byte at a time is cut at the same time: the limit is per line, not per byte
    loris = served.connect()
    started = time.monotonic()
    with pytest.raises((BrokenPipeError, ConnectionResetError)):
        for byte in b'{"cmd": "status"}':
            loris.sock.sendall(bytes([byte]))
            time.sleep(0.05)
    assert time.monotonic() - started < 2.0


def test_a_silent_slot_goes_to_a_newcomer_after_the_idle_timeout(
    served: Served, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(socket_server, "IDLE_TIMEOUT_S", 0.3)
    held = served.fill(socket_server.MAX_CLIENTS)
    # held[0] silent longest beyond doubt: the others ask again a while later (each server thread
    # starts its silence when it is back to reading, in an order a loaded machine may shuffle)
    time.sleep(0.2)
    assert all(line.ask({"cmd": "status"}) is not None for line in held[1:])
    time.sleep(0.4)
    newcomer = served.connect()
    newcomer.send({"cmd": "move", "target_m": 1e-4})
    wait_until(lambda: served.daemon.waiting == 1)
    assert held[0].read() is None  # the one silent longest made room
    assert all(line.ask({"cmd": "status"}) is not None for line in held[1:])  # the others kept theirs
    served.daemon.stopped.set()
    assert newcomer.read() == {"ok": True, "result": {"status": "stopped"}}


def test_a_waiting_move_is_not_cut_by_the_idle_timeout(
    short_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(socket_server, "IDLE_TIMEOUT_S", 0.2)
    served = Served(short_dir, ScriptedDaemon(move_s=1.0))
    try:
        mover = served.connect()
        assert mover.ask({"cmd": "move", "target_m": 1e-4}) == {"ok": True, "result": {"status": "done"}}
        assert mover.ask({"cmd": "status"}) is not None  # the same connection, after 5 idle timeouts
        with Client(served.path, timeout_s=5.0) as client:  # the client's own move, with heartbeats
            assert client.request("move", target_m=1e-4)["ok"] is True
    finally:
        served.close()


def test_a_silent_client_keeps_its_connection_while_there_is_room(
    served: Served, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(socket_server, "IDLE_TIMEOUT_S", 0.2)
    with Client(served.path, timeout_s=5.0) as client:  # connects at once
        time.sleep(0.5)
        assert client.request("status")["ok"] is True
        time.sleep(0.5)
        assert client.request("status")["ok"] is True


def test_beyond_the_cap_a_connection_is_served_in_full_once_a_slot_frees(
    served: Served, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(socket_server, "DOORWAY_TIMEOUT_S", 0.3)
    held = served.fill(socket_server.MAX_CLIENTS)
    late = served.connect()
    for _ in range(8):  # a waiting move's heartbeat: status every 0.1 s, past the doorway's limit
        assert late.ask({"cmd": "status"}) is not None
        time.sleep(0.1)
    held[0].close()
    wait_until(lambda: len(served.server._full) < socket_server.MAX_CLIENTS)  # its thread saw the end
    late.send({"cmd": "move", "target_m": 1e-4})
    wait_until(lambda: served.daemon.waiting == 1)
    served.daemon.stopped.set()
    assert late.read() == {"ok": True, "result": {"status": "stopped"}}


def test_beyond_the_cap_a_silent_connection_is_refused(
    served: Served, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(socket_server, "DOORWAY_TIMEOUT_S", 0.3)
    monkeypatch.setattr(socket_server, "MAX_DOORWAY", 1)
    served.fill(socket_server.MAX_CLIENTS)
    silent = served.connect()
    time.sleep(0.1)
    beyond = served.connect()  # beyond the doorway too: refused at once
    assert beyond.read(timeout_s=1.0) == {"ok": False, "error": REFUSAL}
    assert silent.read(timeout_s=2.0) == {"ok": False, "error": REFUSAL}
    assert silent.read() is None


def test_a_client_that_takes_no_reply_loses_its_slot(served: Served, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(socket_server, "IDLE_TIMEOUT_S", 0.3)
    monkeypatch.setattr(socket_server, "MAX_CLIENTS", 1)
    monkeypatch.setattr(socket_server, "MAX_DOORWAY", 0)
    deaf = served.connect()
    deaf.send({"cmd": "big"})  # 4 MB of reply it never reads
    time.sleep(1.0)
    newcomer = served.connect()
    newcomer.send({"cmd": "move", "target_m": 1e-4})
    wait_until(lambda: served.daemon.waiting == 1)
    served.daemon.stopped.set()
    assert newcomer.read() == {"ok": True, "result": {"status": "stopped"}}


def test_an_unhashable_command_over_the_cap_is_refused_not_a_crash(served: Served) -> None:
    served.fill(socket_server.MAX_CLIENTS)
    late = served.connect()
    assert late.ask({"cmd": ["stop"]}) == {"ok": False, "error": REFUSAL}
    assert late.read() is None
    assert served.connect().ask({"cmd": "stop"}) == {"ok": True, "stopped": True, "dequeued": 0}


def test_a_handler_that_fails_gets_its_client_an_error_reply_and_the_connection_lives_on(
    served: Served, caplog: pytest.LogCaptureFixture
) -> None:
    line = served.connect()
    with caplog.at_level("ERROR", logger=socket_server.__name__):
        reply = line.ask({"cmd": "bug"})
    assert reply == {"ok": False, "error": "internal error (KeyError: 'key'): see the daemon's log"}
    assert "Traceback" in caplog.text or any(r.exc_info for r in caplog.records)
    assert line.ask({"cmd": "status"}) == {"ok": True, "state": "moving", "waiting": 0}


def test_a_handler_sees_its_client_hang_up_but_not_a_client_done_sending(served: Served) -> None:
    """A long request stops when its client closes the connection (killed: no one will read the
    reply); a client that only shut down its sending side, as ``nc -N`` does, still gets it."""
    gone = served.connect()
    gone.send({"cmd": "watch"})
    time.sleep(0.1)
    assert not served.daemon.hung_up.is_set()
    gone.close()
    assert served.daemon.hung_up.wait(2.0)

    assert socket_server.peer_closed(gone.sock)  # closed on this side: gone as well

    served.daemon.hung_up.clear()
    half = served.connect()
    half.send({"cmd": "watch"})
    half.sock.shutdown(socket.SHUT_WR)
    time.sleep(0.3)
    assert served.connect().ask({"cmd": "stop"}) == {"ok": True, "stopped": True, "dequeued": 0}
    assert half.read() == {"ok": True, "hung_up": False}


def test_close_ends_the_accepting_thread(short_dir: Path) -> None:
    """Closing the listening socket does not wake a thread blocked in accept(); the server
    shuts it down first, so no thread (nor its socket) outlives the server."""

    def accepting() -> int:
        return sum(thread.name == "accept" for thread in threading.enumerate())

    before = accepting()
    served = Served(short_dir, ScriptedDaemon())
    assert served.connect().ask({"cmd": "status"}) is not None
    time.sleep(0.1)  # the thread is back in accept()
    assert accepting() == before + 1
    served.close()
    assert accepting() == before
