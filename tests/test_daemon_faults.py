"""Faults and bad input on the daemon's side: nothing crashes, hangs, or loses a record.

Each failure mode of issue #12 that belongs to the daemon is a named test here;
the fault tests count the records before and after.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_control_loop import MODES, SETTINGS, TRUE
from test_daemon_doubles import FakeAmplifier, FakeSensor, FakeWorld
from test_daemon_hil import ROOT, DaemonProcess, base  # noqa: F401

from feeder.daemon.client import Client
from feeder.daemon.control_loop import ControlLoop, Job
from feeder.daemon.store import Store
from feeder.drivers.sensor import PositionSample

pytestmark = pytest.mark.timeout(120)


# -- the state file -------------------------------------------------------------------------


def _daemon_exit(state: Path, sock: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "feeder", "daemon", "--state-dir", str(state), "--socket", str(sock), *extra],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )


@pytest.mark.parametrize(
    "content",
    [
        pytest.param(b"", id="zero-bytes"),
        pytest.param(b"SQLite format 3\x00" + b"\x01" * 40, id="truncated"),
        pytest.param(b"PK\x03\x04 a zip file, not a database" * 10, id="not-sqlite"),
        pytest.param(None, id="foreign-sqlite"),
    ],
)
def test_a_bad_state_file_is_refused_and_left_untouched(base: Path, content: bytes | None) -> None:  # noqa: F811
    state = base / "state"
    state.mkdir(mode=0o700)
    db = state / "feeder.sqlite"
    if content is None:
        conn = sqlite3.connect(db)
        conn.executescript("CREATE TABLE songs (title TEXT); INSERT INTO songs VALUES ('x');")
        conn.close()
    else:
        db.write_bytes(content)
    before = db.read_bytes()
    done = _daemon_exit(state, base / "s.sock")
    assert done.returncode == 2, done.stderr
    lines = [line for line in done.stderr.splitlines() if "error" in line]
    assert len(lines) == 1 and str(db) in lines[0] and "Traceback" not in done.stderr
    assert db.read_bytes() == before


def test_reset_state_moves_the_old_file_aside_and_starts_fresh(base: Path) -> None:  # noqa: F811
    state = base / "state"
    state.mkdir(mode=0o700)
    (state / "feeder.sqlite").write_bytes(b"garbage")
    daemon = DaemonProcess(base, "--reset-state")
    try:
        assert daemon.request("history", limit=5)["moves"] == []
    finally:
        assert daemon.stop() == 0
    aside = list(state.glob("feeder.sqlite.*.bak"))
    assert len(aside) == 1 and aside[0].read_bytes() == b"garbage"


# -- the control socket ----------------------------------------------------------------------

ABUSE = [
    pytest.param(b'{"cmd": "move", "target_m": ' + b"9" * 5000 + b"}\n", id="huge-integer"),
    pytest.param(b'{"cmd": "move", "target_m": ' + b"9" * 400 + b"}\n", id="int-beyond-float"),
    pytest.param(b"[" * 30_000 + b"]" * 30_000 + b"\n", id="deep-nesting"),
    pytest.param(b'{"cmd": "status", "x": "' + b"a" * (1 << 20) + b'"}\n', id="1MiB-line"),
    pytest.param(b'{"cmd": "st\xff\xfeatus"}\n', id="not-utf8"),
    pytest.param(b'{"cmd": "history", "limit": 1e999}\n', id="infinite-limit"),
]


def _exchange(path: Path, data: bytes, read: bool = True) -> dict[str, object] | None:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as conn:
        conn.connect(str(path))  # blocking: waits for room in the backlog
        conn.settimeout(10)
        # a too-long line: the daemon answers and hangs up mid-send
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            conn.sendall(data)
        if not read:
            return None
        reply = conn.makefile("rb").readline()
    return json.loads(reply) if reply else None


@pytest.fixture(scope="module")
def running(tmp_path_factory: pytest.TempPathFactory) -> DaemonProcess:
    daemon = DaemonProcess(tmp_path_factory.mktemp("fd"))
    yield daemon
    assert daemon.stop() == 0


@pytest.mark.parametrize("data", ABUSE)
def test_abusive_requests_get_an_error_reply_and_the_daemon_keeps_answering(
    running: DaemonProcess, data: bytes
) -> None:
    reply = _exchange(running.socket, data)
    assert reply is not None and reply["ok"] is False and reply["error"]
    assert running.request("status")["ok"] is True


def test_half_written_requests_do_not_hold_a_handler(running: DaemonProcess) -> None:
    for _ in range(40):
        _exchange(running.socket, b'{"cmd": "sta', read=False)
    deadline = time.monotonic() + 5  # the handlers see EOF and end
    while True:
        try:
            assert running.request("status")["ok"] is True
            break
        except OSError:
            assert time.monotonic() < deadline


@given(st.binary(max_size=300))
@settings(
    max_examples=150,
    deadline=5000,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
def test_fuzzed_request_lines_always_get_a_json_reply(running: DaemonProcess, data: bytes) -> None:
    line = data.replace(b"\n", b" ") + b"\n"
    if not line.strip():
        return
    reply = _exchange(running.socket, line)
    assert reply is not None and isinstance(reply["ok"], bool)
    if reply["ok"] is False:
        assert isinstance(reply["error"], str)


# -- the sensor and the store ----------------------------------------------------------------


class _GarbageSensor(FakeSensor):
    """Real frames, then ``bad`` ones."""

    def __init__(self, world: FakeWorld, good: int, bad: Callable[[PositionSample], PositionSample]) -> None:
        super().__init__(world)
        self.good = good
        self.bad = bad

    def read(self, timeout_s: float = 1.0) -> PositionSample:
        sample = super().read(timeout_s)
        return self.bad(sample) if self.sequence > self.good else sample


GARBAGE = {
    "nan position": (lambda s: replace(s, position_m=float("nan")), "an impossible position: nan"),
    "huge position": (lambda s: replace(s, position_m=1e308), "an impossible position: 1e+308"),
    "nan pose": (lambda s: replace(s, poses=((s.position_m, float("nan"), 0.0),)), "part 1's y: nan"),
    "huge angle": (lambda s: replace(s, poses=((s.position_m, 0.0, 1e18),)), "part 1's angle: 1e+18"),
}


@pytest.mark.parametrize("garbage", GARBAGE.values(), ids=GARBAGE.keys())
def test_an_impossible_reading_is_a_sensor_fault_and_nothing_invalid_is_stored(
    garbage: tuple[Callable[[PositionSample], PositionSample], str],
) -> None:
    """A NaN or off-plate reading (1e308 m was learned as an infinite step and stored; a NaN pose
    broke every status reply) stops the move as a sensor fault; nothing of it is saved."""
    bad, message = garbage
    world = FakeWorld(TRUE, scatter=0.02, noise_m=0.05e-6, seed=3)
    saved: list[float] = []
    faults: list[str] = []
    amp = FakeAmplifier(world)
    loop = ControlLoop(
        amp,
        _GarbageSensor(world, good=60, bad=bad),
        MODES,
        SETTINGS,
        on_position=lambda x, poses: saved.append(x),
        on_fault=lambda k, m: faults.append(k),
    )
    loop.start()
    try:
        job = Job("move", target_m=900e-6)
        assert loop.submit(job) is None
        assert job.done.wait(20)
        assert loop.position_m is None and loop.sensor_lost is not None
        refused = loop.submit(Job("move", target_m=0.0))
        estimates = loop.estimates()
    finally:
        loop.shutdown()
    assert job.result is not None and job.result.status == "fault"
    assert message in job.result.reason
    assert refused is not None and "sensor" in refused
    assert saved and all(abs(x) < 1e-2 for x in saved)
    assert all(math.isfinite(e.step_m) for e in estimates.values())
    assert not world.moving(time.monotonic())  # stopped, or the burst was over anyway


class _FillingDisk:
    """A store whose writes fail while ``full`` (as SQLite does on a full disk)."""

    def __init__(self, path: Path) -> None:
        self.store = Store(path)
        self.full = False
        self.lock = threading.Lock()

    def _check(self) -> None:
        if self.full:
            raise sqlite3.OperationalError("database or disk is full")

    def save_position(self, x: float, poses: tuple[tuple[float, float, float], ...] = ()) -> None:
        self._check()
        self.store.save_position(x, poses)

    def begin(self, job: Job) -> None:
        self._check()
        job.record_id = self.store.begin_move(job.target_m or 0.0, None)

    def end(self, job: Job, result: object) -> None:
        self._check()
        assert job.record_id is not None
        self.store.finish_move(
            job.record_id,
            status=result.status,
            reason=result.reason,  # type: ignore[attr-defined]
            reached_m=result.reached_m,
            steps=result.steps,  # type: ignore[attr-defined]
            bursts=result.bursts,
            step_forward_m=None,  # type: ignore[attr-defined]
            step_backward_m=None,
        )


def test_disk_full_ends_the_move_refuses_more_and_loses_no_record(tmp_path: Path) -> None:
    world = FakeWorld(TRUE, scatter=0.02, noise_m=0.05e-6, seed=4)
    disk = _FillingDisk(tmp_path / "f.sqlite")
    loop = ControlLoop(
        FakeAmplifier(world), FakeSensor(world), MODES, SETTINGS, on_position=disk.save_position
    )

    def job(target: float) -> Job:
        j = Job("move", target_m=target)
        j.on_start = lambda: disk.begin(j)
        j.on_done = lambda r: disk.end(j, r)
        return j

    loop.start()
    try:
        first = job(100e-6)
        assert loop.submit(first) is None and first.done.wait(20)
        assert loop.writer.flush(5)
        records_before = len(disk.store.moves())
        assert records_before == 1
        second = job(900e-6)
        assert loop.submit(second) is None
        while world.position(time.monotonic()) < 150e-6:
            time.sleep(0.005)
        disk.full = True
        assert second.done.wait(20)  # the move ends although its record cannot be written
        assert second.result is not None and second.result.status == "stopped"
        assert "state store unwritable" in second.result.reason
        refused = loop.submit(job(0.0))
        assert refused is not None and "state store unwritable" in refused
        assert loop.writer.pending() >= 1
        disk.full = False  # space returns: the queued records go in, in order
        deadline = time.monotonic() + 10
        while loop.writer.unwritable is not None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert loop.writer.flush(5)
        moves = disk.store.moves()
        assert loop.submit(job(world.position(time.monotonic()))) is None
    finally:
        loop.shutdown()
    assert len(moves) == records_before + 1
    assert moves[0]["status"] == "done" and moves[1]["status"] == "stopped"
    assert "state store unwritable" in moves[1]["reason"]


def test_a_killed_simulator_is_respawned_on_a_fresh_pty(base: Path) -> None:  # noqa: F811
    daemon = DaemonProcess(base)
    try:
        assert daemon.request("move", target_m=40e-6)["ok"]
        before = daemon.request("status")
        records = len(daemon.request("history", limit=100)["moves"])
        os.kill(before["simulator_pid"], signal.SIGKILL)
        after = daemon.wait_for(
            lambda s: (
                s["simulator_respawns"] == 1 and s["fault"] is None and s["position_state"] == "confirmed"
            ),
            timeout=30,
        )
        moved = daemon.request("move", target_m=after["position_m"] + 30e-6)
        history = daemon.request("history", limit=100)["moves"]
    finally:
        assert daemon.stop() == 0
    assert after["simulator_pid"] != before["simulator_pid"]
    assert (
        after["simulator_endpoints"]["console_pty"] != before["simulator_endpoints"]["console_pty"]
        or after["simulator_endpoints"]["sensor_tcp"] != before["simulator_endpoints"]["sensor_tcp"]
    )
    assert moved["ok"], moved
    # the loss names its cause: the camera died with the simulator and was noticed first
    died = f"the embedded simulator (firmware_sim, pid {before['simulator_pid']}) died (exit code -9): "
    assert after["faults"] and after["faults"][0]["message"].startswith(died), after["faults"]
    assert len(history) == records + 1  # nothing written before was lost
    assert history[0]["status"] == "done"


def test_a_calibration_larger_than_the_travel_plans_within_it() -> None:
    from test_daemon_service import start

    short = Path(tempfile.mkdtemp(prefix="fd"))  # socket paths stay under 108 bytes
    daemon, _ = start(short)
    try:
        with Client(short / "run" / "f.sock", timeout_s=120) as client:
            before = len(client.request("history")["moves"])
            reply = client.request("calibrate", steps=10_000, trace=True)
            after = client.request("move", target_m=0.0)
            history = client.request("history")["moves"]
    finally:
        daemon.shutdown()
        shutil.rmtree(short, ignore_errors=True)
    assert reply["ok"], reply
    assert 2 <= reply["calibration_steps"] < 10_000 and "limited" in reply["note"]
    limits = SETTINGS.min_position_m, SETTINGS.max_position_m
    assert all(limits[0] <= x <= limits[1] for _, x in reply["result"]["trace"])
    assert after["ok"], after  # nothing left the part out of reach
    assert len(history) == before + 1  # the move recorded, nothing lost
