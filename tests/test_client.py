"""``from feeder import Client``: typed calls against the real daemon (fake world), errors and
timeouts against scripted socket servers."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from listener import Listener
from test_daemon_service import start, wait_for

from feeder import Client
from feeder.daemon import client as client_module
from feeder.daemon.client import HEARTBEAT_S, DaemonUnavailable
from feeder.daemon.replies import Accepted, MoveRecord, MoveResult
from feeder.daemon.service import Daemon
from feeder.errors import (
    DaemonError,
    DaemonRefused,
    DaemonTimeout,
    DaemonUnreachable,
    FeederError,
    InputError,
    MoveFailed,
    MoveFaulted,
)

pytestmark = pytest.mark.timeout(60)

Answer = Callable[[dict[str, Any], int], "dict[str, Any] | None"]


class ScriptedServer:
    """A Unix socket server answering each request with ``answer(request, connection_index)``;
    None means never answer (a hung daemon).  Counts requests per command."""

    def __init__(self, path: Path, answer: Answer) -> None:
        self.answer = answer
        self.requests: list[tuple[int, str]] = []
        server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        server.bind(str(path))
        server.listen(8)
        self._conns: list[socket.socket] = []
        self._listener = Listener(server, self._accepted)

    def _accepted(self, conn: socket.socket) -> None:
        threading.Thread(target=self._serve, args=(conn, len(self._conns)), daemon=True).start()
        self._conns.append(conn)

    def _serve(self, conn: socket.socket, index: int) -> None:
        with conn, conn.makefile("rb") as reader:
            for line in reader:
                request = json.loads(line)
                self.requests.append((index, request["cmd"]))
                reply = self.answer(request, index)
                if reply is not None:
                    conn.sendall(json.dumps(reply).encode() + b"\n")

    def close(self) -> None:
        self._listener.close()
        for conn in self._conns:
            conn.close()


@pytest.fixture
def daemon(short_dir: Path) -> Iterator[tuple[Daemon, Path]]:
    running, _ = start(short_dir)
    yield running, short_dir / "run" / "f.sock"
    running.shutdown()


def test_typed_moves_status_history_and_calibration(daemon) -> None:
    _, sock = daemon
    with Client(sock, timeout_s=5.0) as client:
        first = client.move_to(150e-6)
        second = client.move_by(-50e-6)
        status = client.status()
        history = client.history(10)
        calibrated = client.calibrate(8)
    assert isinstance(first, MoveResult) and first.done and first.kind == "move"
    assert first.target_m == 150e-6 and abs(first.error_m or 1.0) <= 1e-6
    assert first.steps > 0 and first.move_id == 1 and first.duration_s > 0
    assert second.target_m == pytest.approx(first.reached_m - 50e-6, abs=0.5e-6)
    assert status.state == "idle" and status.position_state == "confirmed"
    assert status.loop_state == "idle"
    assert status.position_m == pytest.approx(100e-6, abs=1.5e-6)
    assert status.travel_limits_m == (-1e-3, 1e-3) and status.tolerance_m == 1e-6
    assert status.last_result is not None and status.last_result.target_m == second.target_m
    assert status.raw["transport"] == "fake"
    assert [type(m) for m in history] == [MoveRecord, MoveRecord]
    assert [m.target_m for m in history] == [150e-6, second.target_m]
    assert [m.status for m in history] == ["done", "done"]
    assert history[0].steps == first.steps and history[0].reached_m == first.reached_m
    assert not first.steps_estimated and not any(m.steps_estimated for m in history)
    assert calibrated.kind == "calibrate" and calibrated.done
    assert calibrated.estimates["coarse/forward"].steps >= first.estimates["coarse/forward"].steps + 8


def test_refusals_carry_the_daemons_reason(daemon) -> None:
    _, sock = daemon
    client = Client(sock)
    with pytest.raises(DaemonRefused, match="travel limits") as refused:
        client.move_to(1.0)
    assert isinstance(refused.value, FeederError) and refused.value.result is None
    accepted = client.move_to(600e-6, wait=False)
    assert accepted == Accepted(queue_position=0)
    wait_for(lambda: client.status().state == "moving")
    with pytest.raises(DaemonRefused, match="in progress"):
        client.move_to(0.0)
    assert client.move_by(-10e-6, queue=True, wait=False) == Accepted(queue_position=1)
    stopped = client.stop()
    assert stopped.stopped and stopped.dequeued == 1
    assert client.status().queued_moves == 0  # the connection is still good
    client.close()


def test_a_stopped_move_raises_move_failed_with_its_result(daemon) -> None:
    _, sock = daemon
    outcome: list[BaseException | MoveResult] = []

    def mover() -> None:
        try:
            outcome.append(Client(sock).move_to(900e-6))
        except FeederError as err:
            outcome.append(err)

    thread = threading.Thread(target=mover)
    thread.start()
    with Client(sock) as client:
        wait_for(lambda: client.status().state == "moving")
        assert client.stop().stopped
    thread.join(10)
    (failed,) = outcome
    assert isinstance(failed, MoveFailed) and not isinstance(failed, MoveFaulted)
    assert failed.result.status == "stopped" and failed.result.target_m == 900e-6
    assert failed.result.reached_m is not None and failed.result.reached_m < 900e-6


def test_bad_arguments_are_input_errors_before_any_request(daemon) -> None:
    _, sock = daemon
    with Client(sock) as client:
        for call in (
            lambda: client.move_to(float("nan")),
            lambda: client.move_by(float("inf")),
            lambda: client.move_to(True),
            lambda: client.calibrate(1),
            lambda: client.status(timeout_s=0),
        ):
            with pytest.raises(InputError):
                call()
        assert client.history(5) == []  # nothing was moved


def test_unreachable_daemon(short_dir: Path) -> None:
    assert DaemonUnavailable is DaemonUnreachable and issubclass(DaemonUnreachable, DaemonError)
    with pytest.raises(DaemonUnreachable, match="no daemon socket"):
        Client(short_dir / "none.sock")
    stale = socket.socket(socket.AF_UNIX)  # a socket file nobody listens on
    stale.bind(str(short_dir / "stale.sock"))
    stale.close()
    with pytest.raises(DaemonUnreachable, match="no daemon listening"):
        Client(short_dir / "stale.sock")
    (short_dir / "file").write_text("x")
    with pytest.raises(DaemonUnreachable, match="not a socket"):
        Client(short_dir / "file")


def test_a_silent_daemon_times_out_and_the_next_call_reconnects(short_dir: Path) -> None:
    path = short_dir / "s.sock"
    server = ScriptedServer(
        path, lambda req, conn: None if conn == 0 else {"ok": True, "stopped": False, "dequeued": 0}
    )
    try:
        client = Client(path, timeout_s=0.3)
        began = time.monotonic()
        with pytest.raises(DaemonTimeout, match=r"did not answer 'stop' within 0\.3 s") as err:
            client.stop()
        assert 0.29 <= time.monotonic() - began < 1.0 and err.value.timeout_s == 0.3
        assert client.stop().dequeued == 0  # a fresh connection
    finally:
        server.close()


def test_malformed_and_closed_replies_are_unreachable(short_dir: Path) -> None:
    path = short_dir / "s.sock"
    server = ScriptedServer(path, lambda req, conn: {"ok": True, "moves": [{"id": 1}]})
    try:
        with pytest.raises(DaemonUnreachable, match="malformed reply to 'history'"):
            Client(path).history()
    finally:
        server.close()


def _result(status: str, reason: str) -> dict[str, Any]:
    return {
        "kind": "move",
        "status": status,
        "reason": reason,
        "target_m": 1e-4,
        "start_m": 0.0,
        "reached_m": 5e-5,
        "error_m": -5e-5,
        "steps": 3,
        "bursts": 1,
        "duration_s": 0.1,
        "estimates": {},
        "move_id": 7,
    }


def test_result_statuses_map_to_errors(short_dir: Path) -> None:
    path = short_dir / "s.sock"
    ends = iter(
        [("fault", "amplifier lost: no answer"), ("stalled", "no progress"), ("refused", "stop requested")]
    )

    def answer(request: dict[str, Any], conn: int) -> dict[str, Any]:
        status, reason = next(ends)
        return {"ok": False, "result": _result(status, reason), "error": reason}

    server = ScriptedServer(path, answer)
    try:
        client = Client(path)
        with pytest.raises(MoveFaulted, match="move fault: amplifier lost") as fault:
            client.move_to(1e-4)
        assert fault.value.result.move_id == 7
        with pytest.raises(MoveFailed, match="stalled: no progress"):
            client.move_to(1e-4)
        with pytest.raises(DaemonRefused, match="stop requested") as refused:
            client.move_to(1e-4, queue=True)
        assert refused.value.result is not None and refused.value.result.status == "refused"
    finally:
        server.close()


def test_a_move_may_outlast_the_timeout_while_heartbeats_answer(short_dir: Path, monkeypatch) -> None:
    """The timeout bounds each reply (heartbeats included), never the move."""
    path = short_dir / "s.sock"

    def answer(request: dict[str, Any], conn: int) -> dict[str, Any]:
        if request["cmd"] == "move":
            time.sleep(1.0)  # a move 5× longer than the timeout
            return {"ok": True, "result": _result("done", "within tolerance")}
        return {"ok": True, "state": "moving"}

    server = ScriptedServer(path, answer)
    monkeypatch.setattr(client_module, "HEARTBEAT_S", 0.1)
    try:
        result = Client(path, timeout_s=0.2).move_to(1e-4)
    finally:
        server.close()
    assert result.done and result.move_id == 7
    heartbeats = [conn for conn, cmd in server.requests if cmd == "status"]
    assert len(heartbeats) >= 5 and set(heartbeats) == {1}  # one heartbeat connection


def test_a_move_raises_timeout_once_heartbeats_go_unanswered(short_dir: Path) -> None:
    path = short_dir / "s.sock"
    answered: list[int] = []

    def answer(request: dict[str, Any], conn: int) -> dict[str, Any] | None:
        if request["cmd"] == "move" or len(answered) >= 2:
            return None  # the move never ends; then the daemon hangs
        answered.append(conn)
        return {"ok": True, "state": "moving"}

    server = ScriptedServer(path, answer)
    try:
        began = time.monotonic()
        with pytest.raises(DaemonTimeout, match="heartbeat"):
            Client(path, timeout_s=0.5).move_to(1e-4)
        elapsed = time.monotonic() - began
    finally:
        server.close()
    # two answered heartbeats after HEARTBEAT_S each, then a third one unanswered for 0.5 s
    assert 3 * HEARTBEAT_S + 0.5 <= elapsed < 3 * HEARTBEAT_S + 0.5 + 1.0


def test_shutdown_waits_until_the_daemon_is_gone(daemon) -> None:
    running, sock = daemon
    Client(sock).shutdown()
    assert not sock.exists() and running.wait(5)  # the store closes after the socket
    with pytest.raises(DaemonUnreachable):
        Client(sock)
