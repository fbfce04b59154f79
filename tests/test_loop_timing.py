"""The control loop's timing report (``ControlLoop.timing()``) against known lateness.

The tick thread's body runs on the test's thread with the loop's injectable clock and a
scripted sleep: time passes only while the tick sleeps, and each sleep overshoots its
deadline by the next scripted lateness, so every tick's lateness (wake-up − deadline) and
every overrun (a tick whose work ran past the next deadline) is known exactly, whatever
the machine's load.  No real time is slept.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from types import SimpleNamespace

import numpy as np
import pytest
from test_daemon_doubles import FakeAmplifier, FakeSensor, FakeWorld

import feeder.daemon.control_loop as control_loop
from feeder.daemon.control_loop import COARSE, FINE, ControlLoop, LoopSettings, StepMode
from feeder.drivers.amplifier import DriveSettings

pytestmark = pytest.mark.timeout(60)

PERIOD_S = 0.01  # 100 Hz
MODES = {
    COARSE: StepMode(COARSE, DriveSettings(1000.0, 100.0), 3.0e-6, (2.5e-6, 3.5e-6)),
    FINE: StepMode(FINE, DriveSettings(1000.0, 40.0), 0.7e-6, (0.5e-6, 0.9e-6)),
}


RunTicks = Callable[[list[float]], dict[str, float | int | str]]


class ScriptEnd(Exception):
    """The scripted lateness ran out: the tick thread's body returns to the test."""


class ScriptedTime:
    """The loop's clock (s) and its sleep: sleeping ``d`` s advances the clock by ``d`` plus the
    next scripted lateness."""

    def __init__(self, lateness_s: Iterable[float]) -> None:
        self.now = 1000.0
        self._lateness = iter(lateness_s)
        self.sleeps = 0

    def clock(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        late = next(self._lateness, None)
        if late is None:
            raise ScriptEnd
        self.sleeps += 1
        self.now += seconds + late


@pytest.fixture
def world() -> FakeWorld:
    return FakeWorld({(100.0, 1): 3e-6, (100.0, -1): 3e-6, (40.0, 1): 7e-7, (40.0, -1): 7e-7})


@pytest.fixture
def run_ticks(world: FakeWorld, monkeypatch: pytest.MonkeyPatch) -> Iterator[RunTicks]:
    """``run_ticks(lateness)``: a loop at 100 Hz, ticked once per scripted lateness; its timing()."""
    loops: list[ControlLoop] = []

    def run(lateness_s: list[float]) -> dict[str, float | int | str]:
        scripted = ScriptedTime(lateness_s)
        loop = ControlLoop(
            FakeAmplifier(world),
            FakeSensor(world),
            MODES,
            LoopSettings(rate_hz=1 / PERIOD_S),
            clock=scripted.clock,
            collect_in_slack=False,
        )
        loops.append(loop)
        with monkeypatch.context() as patch:
            # the loop's module alone sees the scripted sleep; other threads keep time.sleep
            fake_time = SimpleNamespace(
                sleep=scripted.sleep, monotonic=scripted.clock, process_time=time.process_time
            )
            patch.setattr(control_loop, "time", fake_time)
            with pytest.raises(ScriptEnd):
                loop._tick_until_shutdown()
        assert scripted.sleeps == len(lateness_s) == loop.ticks  # one sleep per tick
        np.testing.assert_allclose(loop.lateness.last(loop.ticks), lateness_s, atol=1e-9)
        return loop.timing()

    yield run
    for loop in loops:
        loop.shutdown()


def test_ticks_that_wake_past_the_next_deadline_are_counted_as_overruns(run_ticks: RunTicks) -> None:
    """Three of 30 ticks wake 25 ms late (2.5 periods: their work ends past the next deadline);
    the others 1 ms late.  The missed deadlines are skipped: the tick after an overrun is on
    time again, not late."""
    lateness = [0.001] * 30
    for k in (4, 12, 20):
        lateness[k] = 0.025
    timing = run_ticks(lateness)
    assert timing["ticks"] == 30
    assert timing["overruns"] == 3
    assert timing["jitter_max_s"] == pytest.approx(0.025, abs=1e-9)
    assert timing["jitter_p50_s"] == pytest.approx(0.001, abs=1e-9)


def test_late_ticks_within_a_period_are_no_overruns(run_ticks: RunTicks) -> None:
    timing = run_ticks([0.009, 0.0005, 0.008, 0.0001] * 5)
    assert timing["ticks"] == 20 and timing["overruns"] == 0
    assert timing["jitter_max_s"] == pytest.approx(0.009, abs=1e-9)


def test_jitter_percentiles_of_a_known_lateness_distribution(run_ticks: RunTicks) -> None:
    """1000 ticks: 980 wake 0.5 ms late, 15 wake 4 ms late, 5 wake 9 ms late.  The p99 (linear
    interpolation, as numpy's) is 4 ms: the 1.5 % tail beyond 0.5 ms, below the 9 ms maximum."""
    lateness = [0.0005] * 1000
    for k in range(15):
        lateness[40 + 60 * k] = 0.004
    for k in range(5):
        lateness[70 + 190 * k] = 0.009
    timing = run_ticks(lateness)
    assert timing["ticks"] == 1000 and timing["overruns"] == 0
    assert timing["jitter_p50_s"] == pytest.approx(0.0005, abs=1e-9)
    assert timing["jitter_p99_s"] == pytest.approx(0.004, abs=1e-9)
    assert timing["jitter_p99_s"] == pytest.approx(np.percentile(lateness, 99), abs=1e-9)
    assert timing["jitter_max_s"] == pytest.approx(0.009, abs=1e-9)
