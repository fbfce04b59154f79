"""The console's limits (feeder/web/): STOP and status are answered at once however many moves
wait for their result, the waiting moves are bounded (503 beyond), and numbers or limits the
daemon cannot take get a 400 naming the field, never a 500.

A scripted handler stands in for the daemon where the daemon's own behaviour does not matter
(its moves wait until a stop); the last test runs the service on the in-process fake world."""

from __future__ import annotations

import http.client
import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("starlette")
pytest.importorskip("uvicorn")

from test_http_console import Console

from feeder.daemon.config import HttpConfig
from feeder.daemon.quiet_window import QuietWindow
from feeder.web import lanes
from feeder.web.server import ConsoleServer

pytestmark = pytest.mark.timeout(60)
TOKEN = "t" * 43
MANY_MOVES = 45
"""More than anyio's 40 worker threads, which starlette shares between every request."""


class ScriptedDaemon:
    """The console's :class:`~feeder.web.app.Handler`: a move waits until a stop, as a queued
    move waits for the one before it."""

    def __init__(self) -> None:
        self.quiet = QuietWindow()
        self.stopped = threading.Event()
        self.waiting = 0
        self._lock = threading.Lock()

    def handle(self, request: Any) -> dict[str, Any]:
        self.quiet.hold()
        cmd = request.get("cmd")
        if cmd == "stop":
            self.stopped.set()
            return {"ok": True, "stopped": True, "dequeued": 0}
        if cmd == "status":
            return {"ok": True, "state": "moving", "axes": {"x": {}}, "estimates": {}}
        if cmd == "history":
            return {"ok": True, "moves": [], "limit": request["limit"]}
        if cmd in ("move", "calibrate"):
            with self._lock:
                self.waiting += 1
            self.stopped.wait(30)
            with self._lock:
                self.waiting -= 1
            return {"ok": False, "error": "stop requested", "result": {"status": "stopped"}}
        return {"ok": False, "error": f"unknown cmd {cmd!r}"}


def call(
    port: int, method: str, path: str, body: Any = None, timeout_s: float = 30.0
) -> tuple[int, dict[str, Any], dict[str, str]]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout_s)
    data = body if isinstance(body, bytes) else (None if body is None else json.dumps(body).encode())
    try:
        conn.request(method, path, body=data, headers={"Authorization": f"Bearer {TOKEN}"})
        response = conn.getresponse()
        return response.status, json.loads(response.read()), dict(response.getheaders())
    finally:
        conn.close()


class Scripted:
    def __init__(self) -> None:
        self.daemon = ScriptedDaemon()
        self.server = ConsoleServer(
            self.daemon, HttpConfig(port=0, moves_per_s=1000.0, move_burst=1000), TOKEN
        )
        self.server.start()
        self.port = self.server.port

    def call(
        self, method: str, path: str, body: Any = None, timeout_s: float = 30.0
    ) -> tuple[int, dict[str, Any], dict[str, str]]:
        return call(self.port, method, path, body, timeout_s)


@pytest.fixture
def scripted() -> Iterator[Scripted]:
    running = Scripted()
    yield running
    running.daemon.stopped.set()
    running.server.stop()


def wait_until(condition: Any, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_stop_and_status_are_answered_at_once_while_many_moves_wait(scripted: Scripted) -> None:
    answers: list[tuple[int, dict[str, Any], dict[str, str]]] = []

    def move(i: int) -> None:
        body = {"target_m": -4.5e-3 if i % 2 else 4.5e-3, "queue": True}
        answers.append(scripted.call("POST", "/api/move", body))

    movers = [threading.Thread(target=move, args=(i,), daemon=True) for i in range(MANY_MOVES)]
    for thread in movers:
        thread.start()
    wait_until(lambda: scripted.daemon.waiting >= lanes.MAX_WAITING_MOVES)
    time.sleep(0.5)  # the rest arrive (and, before the lanes, took the shared pool's last threads)
    started = time.monotonic()
    code, status, _ = scripted.call("GET", "/api/status", timeout_s=3.0)
    status_s = time.monotonic() - started
    started = time.monotonic()
    stop_code, stopped, _ = scripted.call("POST", "/api/stop", timeout_s=3.0)
    stop_s = time.monotonic() - started
    assert (code, status["state"]) == (200, "moving")
    assert (stop_code, stopped["stopped"]) == (200, True)
    assert status_s < 2.0 and stop_s < 2.0, (status_s, stop_s)  # measured: a few ms
    for thread in movers:
        thread.join(10)
    codes = sorted(code for code, _, _ in answers)
    assert codes == [200] * lanes.MAX_WAITING_MOVES + [503] * (MANY_MOVES - lanes.MAX_WAITING_MOVES)
    busy = [(reply, headers) for code, reply, headers in answers if code == 503]
    assert all(
        "too many moves waiting" in reply["error"] and headers["retry-after"] == "1"
        for reply, headers in busy
    )


def test_moves_beyond_the_bound_get_503_and_the_slots_come_back(scripted: Scripted) -> None:
    threads = [
        threading.Thread(target=scripted.call, args=("POST", "/api/calibrate", {"steps": 20}), daemon=True)
        for _ in range(lanes.MAX_WAITING_MOVES)
    ]
    for thread in threads:
        thread.start()
    wait_until(lambda: scripted.daemon.waiting == lanes.MAX_WAITING_MOVES)
    for _ in range(3):
        assert scripted.call("POST", "/api/move", {"target_m": 1e-4})[0] == 503
    assert scripted.call("POST", "/api/stop")[0] == 200
    for thread in threads:
        thread.join(10)
    scripted.daemon.stopped.clear()
    threads = [
        threading.Thread(target=scripted.call, args=("POST", "/api/move", {"target_m": 1e-4}), daemon=True)
        for _ in range(lanes.MAX_WAITING_MOVES)
    ]
    for thread in threads:
        thread.start()
    wait_until(lambda: scripted.daemon.waiting == lanes.MAX_WAITING_MOVES)  # every slot free again
    scripted.daemon.stopped.set()
    for thread in threads:
        thread.join(10)


@pytest.mark.parametrize(
    ("method", "path", "body", "field"),
    [
        ("POST", "/api/move", b'{"target_m": 1' + b"0" * 400 + b"}", "target_m"),
        ("POST", "/api/move", b'{"by_m": -1' + b"0" * 400 + b"}", "by_m"),
        ("POST", "/api/move", b'{"x_m": 0, "y_m": 1' + b"0" * 4000 + b"}", "y_m"),
        ("POST", "/api/move", b'{"angle_rad": 1' + b"0" * 309 + b"}", "angle_rad"),
        ("GET", "/api/history?limit=%C2%B2", None, "limit"),  # superscript two: isdigit() says yes
        ("GET", "/api/history?limit=%D9%A3", None, "limit"),  # Arabic-Indic three
        ("GET", "/api/history?limit=" + "9" * 5000, None, "limit"),  # past int()'s 4300 digits
        ("GET", "/api/history?limit=1" + "0" * 20, None, "limit"),
    ],
)
def test_numbers_the_daemon_cannot_take_get_400_naming_the_field(
    scripted: Scripted, method: str, path: str, body: bytes | None, field: str
) -> None:
    code, reply, _ = scripted.call(method, path, body)
    assert code == 400, reply
    assert reply["ok"] is False and reply["error"].startswith(field) and len(reply["error"]) < 200, reply
    assert scripted.daemon.waiting == 0
    assert scripted.call("GET", "/api/history?limit=7")[1]["limit"] == 7  # an ASCII limit still passes


def test_a_huge_jog_is_refused_in_one_short_line(scripted: Scripted) -> None:
    code, reply, _ = scripted.call("POST", "/api/jog", b'{"axis": "x", "steps": 1' + b"0" * 400 + b"}")
    assert code == 400 and reply["error"].startswith("steps") and len(reply["error"]) < 200, reply


def test_stop_reaches_the_daemon_past_waiting_moves_and_empties_its_queue(
    short_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(lanes, "MAX_WAITING_MOVES", 4)
    console = Console(short_dir, moves_per_s=1000.0, move_burst=1000)
    answers: list[int] = []
    try:
        assert console.call("POST", "/api/move", {"target_m": 900e-6, "wait": False})[0] == 200

        def queued(i: int) -> None:
            answers.append(
                console.call("POST", "/api/move", {"target_m": -900e-6 if i % 2 else 900e-6, "queue": True})[
                    0
                ]
            )

        threads = [threading.Thread(target=queued, args=(i,), daemon=True) for i in range(6)]
        for thread in threads:
            thread.start()
        wait_until(lambda: answers.count(503) == 2)  # the two beyond the lane's slots: at once
        wait_until(lambda: console.call("GET", "/api/status")[1]["queued_moves"] >= 3)
        started = time.monotonic()
        code, reply, _ = console.call("POST", "/api/stop")
        assert code == 200 and reply["dequeued"] >= 3 and time.monotonic() - started < 2.0, reply
        for thread in threads:
            thread.join(10)
        assert sorted(answers) == [200] * 4 + [503] * 2  # each waiting move got its (stopped) result
    finally:
        console.stop()
