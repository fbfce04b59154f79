"""What the ANC300 driver sends: the amplitude's resolution, no ``stepw`` it cannot finish, and
a cut burst's steps counted from when the unit acted.

Over a pty to firmware_sim's ANC300-dialect console, which keeps every line it was sent
(docs/anc300-protocol.md: ``setv AXIS V`` takes the amplitude; ``stepw`` holds the serial
console, its only session, until the burst is over).
"""

from __future__ import annotations

import statistics
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest
from test_anc300_real_unit import RecordingSession

from feeder.drivers.amplifier import DriveSettings
from feeder.drivers.anc300 import BURST_END_MARGIN_S, Anc300Amplifier
from feeder.drivers.anc300_link import Anc300Link
from firmware_sim.clock import RealTimeClock
from firmware_sim.firmware import Firmware, FirmwareConfig
from firmware_sim.transports import PtyConsole

pytestmark = pytest.mark.timeout(60)


@dataclass
class Unit:
    firmware: Firmware
    link: Anc300Link
    lines: list[str] = field(default_factory=list)


WORK_S = 0.200
"""How long :class:`AnswersAfterWork` works after acting on ``stepu`` before it answers."""


class AnswersAfterWork(RecordingSession):
    """A unit that acts on ``stepu`` as the line arrives and answers :data:`WORK_S` later
    (firmware_sim regenerates 100 ms of waveform first: 6-10 ms; ``stop`` answers in ~1 ms)."""

    def feed(self, data: bytes) -> bytes:
        reply = super().feed(data)
        if b"stepu" in data:
            time.sleep(WORK_S)
        return reply


def open_unit(firmware: Firmware, session: type[RecordingSession] = RecordingSession) -> Iterator[Unit]:
    lines: list[str] = []
    # a stepw the test did not expect gives up after 0.5 s instead of holding the pty
    pty = PtyConsole(lambda _source: session(firmware, lines, wait_timeout_s=0.5))
    link = Anc300Link(pty.path, timeout_s=1.0)
    try:
        yield Unit(firmware, link, lines)
    finally:
        firmware.shutdown()
        link.close()
        pty.close()


@pytest.fixture
def unit() -> Iterator[Unit]:
    """A console on a firmware whose tick does not run: a burst never ends."""
    yield from open_unit(Firmware())


def open_ticking_unit(session: type[RecordingSession]) -> Iterator[Unit]:
    """A console on a firmware ticking in real time (its watchdog relaxed to 5 s: a loaded
    machine's stall must not ground the burst under test)."""
    firmware = Firmware(FirmwareConfig(watchdog_s=5.0))
    stop = threading.Event()
    thread = threading.Thread(target=firmware.run, args=(RealTimeClock(), stop), daemon=True)
    thread.start()
    try:
        yield from open_unit(firmware, session)
    finally:
        stop.set()
        thread.join(timeout=5)


@pytest.fixture
def ticking_unit() -> Iterator[Unit]:
    yield from open_ticking_unit(RecordingSession)


@pytest.fixture
def slow_answering_unit() -> Iterator[Unit]:
    yield from open_ticking_unit(AnswersAfterWork)


def test_the_amplitude_reaches_the_unit_with_microvolt_resolution(unit: Unit) -> None:
    amp = Anc300Amplifier(unit.link, axis=1)
    amp.apply(DriveSettings(frequency_hz=100.0, amplitude_v=37.123456))
    assert "setv 1 37.123456" in unit.lines
    assert unit.firmware.axis(1).status().amplitude_v == pytest.approx(37.123456, abs=1e-9)
    assert amp.status().amplitude_v == pytest.approx(37.123456, abs=1e-9)  # getv: six decimals
    amp.apply(DriveSettings(frequency_hz=100.0, amplitude_v=0.000004))
    assert "setv 1 0.000004" in unit.lines
    assert unit.firmware.axis(1).status().amplitude_v == pytest.approx(4e-6, abs=1e-12)


def test_wait_shorter_than_the_burst_returns_false_after_the_timeout_without_stepw(unit: Unit) -> None:
    """The burst needs 0.15 s more (by the driver's clock), the caller waits 0.1 s: a ``stepw``
    then could not be answered in time (it would time out and drop the link), so none is sent."""
    now = [0.0]
    amp = Anc300Amplifier(unit.link, axis=1, clock=lambda: now[0])
    amp.apply(DriveSettings(frequency_hz=100.0, amplitude_v=20.0))
    amp.enable()
    amp.step(50)  # 0.5 s at the unit's 100 Hz
    now[0] = 0.5 + BURST_END_MARGIN_S - 0.15
    assert amp.wait(0.1) is False
    assert not any(line.startswith("stepw") for line in unit.lines), unit.lines
    steps, estimated = amp.steps_played()
    assert estimated and 0 < steps < 50  # still running by the clock
    assert amp.status().moving
    amp.ground()


def test_wait_longer_than_the_burst_confirms_its_end_with_stepw(ticking_unit: Unit) -> None:
    amp = Anc300Amplifier(ticking_unit.link, axis=1)
    amp.apply(DriveSettings(frequency_hz=100.0, amplitude_v=20.0))
    amp.enable()
    amp.step(3)  # 30 ms
    assert amp.wait(5.0) is True
    assert "stepw 1" in ticking_unit.lines
    assert amp.steps_played() == (3, False)
    assert ticking_unit.firmware.axis(1).status().step_counter == 3
    amp.ground()


def test_a_cut_burst_counts_from_when_the_unit_acted_not_from_its_late_answer(
    slow_answering_unit: Unit,
) -> None:
    """The unit starts the burst as ``stepu`` arrives and answers 200 ms later; ``stop``
    answers at once.  The midpoints of the two round trips (the driver before 2026-11-28) put
    the start 100 ms late: 100 steps short at 1 kHz.  The line's arrival (its sending plus half
    the link's shortest round trip) counts them within the machine's scheduling noise: the
    unit here is a thread of the test's process, and loaded parallel runs made it act on a
    ``stop`` 39 and 78 ms late (errors 8, -2, -39; 1, -4, -21, -78, -9), so the median of
    five bursts is judged, against a bound well inside the old driver's error."""
    unit = slow_answering_unit
    amp = Anc300Amplifier(unit.link, axis=1)
    amp.apply(DriveSettings(frequency_hz=1000.0, amplitude_v=20.0))
    amp.enable()
    errors = []
    for _ in range(5):
        before, true_before = amp.steps_played()[0], unit.firmware.axis(1).status().step_counter
        amp.step(3000)
        time.sleep(0.1)
        amp.stop()
        time.sleep(0.02)  # the ticks count what the DAC played
        played, estimated = amp.steps_played()
        assert estimated
        errors.append((played - before) - (unit.firmware.axis(1).status().step_counter - true_before))
    amp.ground()
    assert abs(statistics.median(errors)) <= 30, errors  # steps = ms at 1 kHz
