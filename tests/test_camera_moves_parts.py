"""The pieces of the daemon's camera calibration (feeder/daemon/camera_moves.py), without I/O
waits beyond a few ms: the executor lends its amplifiers, the sensor feed hands its next sample
to a second reader, the request's fields are checked, and a stop ends the moves grounded."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from test_daemon_doubles import FakeAmplifier, FakeSensor, FakeWorld
from test_offset_moves import CONFIGURED, OffsetPlate, rig

from feeder.cli import main
from feeder.daemon.camera_moves import HANG_UP_POLL_S, PlateMoves, stop_on_hang_up, summary
from feeder.daemon.client import Client
from feeder.daemon.executor import AmplifierExecutor
from feeder.daemon.jobs import Command, StepMode
from feeder.daemon.request_fields import RequestFieldError
from feeder.daemon.requests import answer
from feeder.daemon.sensor_feed import SensorFeed
from feeder.drivers.amplifier import DriveSettings
from feeder.drivers.sensor import SensorLost
from feeder.vision.offset_moves import (
    FIRMWARE_SIM_GAIN_M_PER_V,
    SLIP_FRACTION,
    STEADY_FRAMES,
    MovesStopped,
    OffsetMoves,
    measure,
)


class SlowAmplifier(FakeAmplifier):
    """``ground`` takes ``delay_s``: a command in flight when the amplifiers are lent."""

    def __init__(self, world: FakeWorld, delay_s: float) -> None:
        super().__init__(world)
        self.delay_s = delay_s

    def ground(self) -> None:
        time.sleep(self.delay_s)
        super().ground()


def test_the_executor_lends_its_amplifiers_after_the_command_in_flight_and_queues_meanwhile() -> None:
    amp = SlowAmplifier(FakeWorld({(50.0, 1): 1e-6}), delay_s=0.2)
    mode = StepMode("coarse", DriveSettings(1000.0, 50.0), 1e-6, (0.5e-6, 1.5e-6))
    executor = AmplifierExecutor(amp, {"x": {"coarse": mode}})
    try:
        executor.submit(Command("ground"))
        time.sleep(0.05)  # the ground is in flight
        started = time.monotonic()
        with executor.lent() as amplifiers:
            waited = time.monotonic() - started
            assert amplifiers == {"x": amp} and amp.calls == ["ground"]  # the ground is over
            executor.submit(Command("enable"))
            time.sleep(0.1)
            assert amp.calls == ["ground"]  # the enable waits for the lender
        deadline = time.monotonic() + 2.0
        while "enable" not in amp.calls and time.monotonic() < deadline:
            time.sleep(0.005)
        assert amp.calls[0] == "ground" and "enable" in amp.calls
        assert 0.1 < waited < 0.3
    finally:
        executor.close()


def test_the_feed_hands_its_next_sample_to_a_second_reader_and_the_loop_still_takes_it() -> None:
    feed = SensorFeed(FakeSensor(FakeWorld({}), rate_hz=100.0), timeout_s=1.0, clock=time.monotonic)
    try:
        time.sleep(0.05)
        feed.take()
        first = feed.next_sample(1.0)
        second = feed.next_sample(1.0)
        assert second.sequence > first.sequence  # each read waits for a new sample
        assert second.sequence in {sample.sequence for _, sample in feed.take()}
    finally:
        feed.close()
    with pytest.raises(SensorLost):
        feed.next_sample(0.05)


PLATE = PlateMoves(0.0, 150.0, 1e-3, (2048, 2048), stack_gain_m_per_v=None, travel_outside=lambda _: None)


def test_the_requests_moves_are_checked_field_by_field() -> None:
    moves = PLATE.moves({"volts": 60, "stack_gain_m_per_v": 8e-8, "increment_v": 0.02, "frames": 3})
    assert (moves.volts, moves.stack_gain_m_per_v, moves.increment_v, moves.frames) == (60, 8e-8, 0.02, 3)
    assert moves.lever_arm_m == 1e-3
    simulated = PlateMoves(0.0, 200.0, 1e-3, (2048, 2048), FIRMWARE_SIM_GAIN_M_PER_V, lambda _: None).moves(
        {}
    )
    assert (simulated.volts, simulated.stack_gain_m_per_v) == (100.0, FIRMWARE_SIM_GAIN_M_PER_V)
    stated = dataclasses.replace(PLATE, stack_gain_m_per_v=5e-8)  # hardware with [stack] gain_m_per_v
    assert stated.moves({}).stack_gain_m_per_v == 5e-8
    assert stated.moves({"stack_gain_m_per_v": 8e-8}).stack_gain_m_per_v == 8e-8  # the request's wins
    assert stated.moves({}).slip_fraction == SLIP_FRACTION
    assert stated.moves({"slip_fraction": 0.03}).slip_fraction == 0.03
    for request, named in [
        ({"stack_gain_m_per_v": 8e-8, "volts": 151}, "volts must be in [1, 150]"),
        ({"stack_gain_m_per_v": 8e-8, "volts": "100"}, "volts must be a finite number of volts"),
        ({}, "stack_gain_m_per_v is required on hardware"),
        ({"stack_gain_m_per_v": 1.0}, "stack_gain_m_per_v must be in [1e-12, 1e-3] m/V"),
        ({"stack_gain_m_per_v": 8e-8, "increment_v": 2.0}, "increment_v must be in [0.0001, 1]"),
        ({"stack_gain_m_per_v": 8e-8, "frames": 0}, "frames must be an integer in [1, 1000]"),
        ({"stack_gain_m_per_v": 8e-8, "slip_fraction": 0.5}, "slip_fraction must be in [0.001, 0.2]"),
    ]:
        with pytest.raises(RequestFieldError, match=named.replace("[", r"\[")):
            PLATE.moves(request)


def test_a_stop_ends_the_moves_within_an_increment_every_axis_grounded() -> None:
    plate = OffsetPlate()
    axes, camera = rig(plate)
    stop = threading.Event()
    # before x's move: STEADY_FRAMES read; then during x's offset
    camera.on_read = lambda frames: stop.set() if frames > STEADY_FRAMES else None
    with pytest.raises(MovesStopped, match="stopped on axis x"):
        measure(axes, camera, CONFIGURED, plate.moves, stop=stop)
    assert plate.volts == {"x": 0.0, "y": 0.0, "theta": 0.0}
    assert axes["y"].grounded_at == [0.0, 0.0] and axes["theta"].grounded_at == [0.0, 0.0]
    assert axes["x"].grounded_at[-1] == pytest.approx(plate.moves.volts)  # grounded where it stood


class _Daemon:
    """What the request handler sees of a daemon: its setup and the moves it would make."""

    def __init__(self) -> None:
        self.setup = type("Setup", (), {"plate_moves": PLATE})()
        self.asked: list[tuple[OffsetMoves, bool]] = []

    def camera_moves(self, moves: OffsetMoves, save: bool, hung_up: Callable[[], bool]) -> dict[str, object]:
        self.asked.append((moves, save))
        return {"saved": save}


def test_a_request_with_an_unknown_field_moves_nothing() -> None:
    """A typo (``volt``) must not leave the offset at its 100 V default."""
    daemon = _Daemon()
    reply = answer(daemon, {"cmd": "calibrate_camera", "volt": 40, "stack_gain_m_per_v": 7e-8})
    assert reply["ok"] is False and reply["error"].startswith("unknown field 'volt'; known: cmd, frames")
    reply = answer(daemon, {"cmd": "calibrate_camera", "stack_gain_m_per_v": 7e-8, "save": "yes"})
    assert reply == {"ok": False, "error": "save must be true or false, got 'yes'"}
    assert daemon.asked == []
    reply = answer(daemon, {"cmd": "calibrate_camera", "stack_gain_m_per_v": 7e-8, "volts": 40, "save": True})
    assert reply["ok"] is True and reply["calibration"]["image_px"] == [2048, 2048]
    assert daemon.asked[0][0].volts == 40 and daemon.asked[0][1] is True


def test_a_calibration_the_running_daemon_could_not_use_is_neither_stored_nor_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The daemon does not store a calibration with which its travel leaves the camera's view
    (every move would be refused, and its next start); the command says so and writes nothing."""
    report = {
        "warnings": [],
        "slipped": False,
        "saved": False,
        "travel_outside": "the travel x [...] reaches beyond",
    }
    monkeypatch.setattr(Client, "__init__", lambda self, *a, **k: None)
    monkeypatch.setattr(Client, "close", lambda self: None)
    monkeypatch.setattr(Client, "calibrate_camera", lambda self, **fields: dict(report))
    out = tmp_path / "camera.json"
    code = main(["vision", "calibrate-moves", "--daemon", "--save-state", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1 and "would refuse every move: the travel x [...] reaches beyond" in err
    assert "nothing stored or written" in err and not out.exists()


def test_the_moves_stop_when_their_client_hangs_up_and_only_then() -> None:
    """``stop`` is set once ``hung_up()`` turns true, within a poll; never after the moves ended."""
    stop, gone = threading.Event(), threading.Event()
    with stop_on_hang_up(gone.is_set, stop):
        assert not stop.wait(2.5 * HANG_UP_POLL_S)
        gone.set()
        assert stop.wait(2.5 * HANG_UP_POLL_S)
    stop, gone = threading.Event(), threading.Event()
    with stop_on_hang_up(gone.is_set, stop):
        pass
    gone.set()
    assert not stop.wait(2.5 * HANG_UP_POLL_S)


def test_the_logged_summary_names_what_was_measured() -> None:
    """The log's line: O when θ moved, and says it was not measured when it did not."""
    report = {"pixel_size_m": 2.6918e-6, "rotation_rad": 0.3965, "mirrored": True, "returned_px": 0.008}
    turned = summary({**report, "origin_x_px": 1022.06, "origin_y_px": 1024.9, "saved": True})
    assert turned == (
        "2.6918 µm/px, turned 0.3965 rad, mirrored, O at (1022.1, 1024.9) px, back within 0.008 px; "
        "stored, used from the next move on"
    )
    assert ", O not measured (no θ axis), " in summary({**report, "origin_x_px": None, "saved": False})
