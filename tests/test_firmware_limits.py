"""Firmware safety limits in virtual time: watchdogs, re-arming, offset and burst ranges.

docs/anc300-protocol.md (``--watchdog-s``, ``--host-watchdog-s``, ``seta``: "offset, within
the rails") and docs/canopen.md (the step counter and step command are I32: a burst is at
most 2³¹ − 1 steps).
"""

from __future__ import annotations

import pytest
from test_firmware import LateClock

from firmware_sim.clock import VirtualClock
from firmware_sim.console import ConsoleSession
from firmware_sim.faults import Fault, FirmwareError, LimitError
from firmware_sim.firmware import Firmware, FirmwareConfig

I32_MAX = 2**31 - 1


def running_axis(fw: Firmware, number: int = 1) -> None:
    """Axis ``number`` stepping continuously at 10 V, 100 Hz."""
    axis = fw.axis(number)
    axis.set_amplitude(10.0)
    axis.set_mode("stp")
    axis.run_continuous(up=True)


def console(fw: Firmware) -> ConsoleSession:
    session = ConsoleSession(fw, dialect="anc300", wait_timeout_s=0.5)
    session.feed(b"echo off\r\n")
    return session


def reply(session: ConsoleSession, line: str) -> list[str]:
    return session.feed(line.encode() + b"\r\n").decode("ascii").split("\r\n")[:-1]


# -- the tick watchdog ----------------------------------------------------------------------


def test_a_tick_later_than_watchdog_s_grounds_every_axis_even_below_twice_it() -> None:
    """watchdog_s = 50 ms; one tick wakes 80 ms late (more than the limit, less than twice it)."""
    fw = Firmware(FirmwareConfig(watchdog_s=0.05))
    running_axis(fw)
    fw.run(LateClock(3, 0.08), max_ticks=6)
    assert fw.tick_summary()["jitter_max_s"] == pytest.approx(0.08)
    for n in fw.axis_numbers:
        status = fw.axis(n).status()
        assert status.faults == ("watchdog",) and status.mode == "gnd" and not status.moving


def test_a_tick_late_by_less_than_watchdog_s_latches_nothing() -> None:
    fw = Firmware(FirmwareConfig(watchdog_s=0.05))
    running_axis(fw)
    fw.run(LateClock(3, 0.04), max_ticks=6)
    status = fw.axis(1).status()
    assert status.fault_word == 0 and status.mode == "stp" and status.moving


# -- the host watchdog ------------------------------------------------------------------------


def test_the_host_watchdog_grounds_an_axis_in_a_finite_burst() -> None:
    """A 10 s burst (1000 steps at 100 Hz) is moving: with no host command for longer than
    host_watchdog_s it is grounded like continuous motion, long before its end."""
    fw = Firmware(FirmwareConfig(host_watchdog_s=0.05))
    clock = VirtualClock()
    axis = fw.axis(1)
    axis.set_amplitude(10.0)
    axis.set_mode("stp")
    axis.step(1000)
    for _ in range(4):  # the host keeps talking: 30 ms between commands
        fw.run(clock, max_ticks=30)
        fw.host_activity()
    status = axis.status()
    assert status.moving and status.fault_word == 0
    fw.run(clock, max_ticks=80)  # 80 ms of silence
    status = axis.status()
    assert status.faults == ("host_watchdog",)
    assert status.mode == "gnd" and not status.moving
    assert 0 < status.step_counter < 1000


def test_the_host_watchdog_leaves_an_idle_axis_alone() -> None:
    fw = Firmware(FirmwareConfig(host_watchdog_s=0.05))
    axis = fw.axis(1)
    axis.set_amplitude(10.0)
    axis.set_mode("stp")
    fw.run(VirtualClock(), max_ticks=120)
    assert axis.status().fault_word == 0 and axis.status().mode == "stp"


# -- re-arming after a watchdog ---------------------------------------------------------------


def test_selecting_a_stepping_mode_rearms_an_axis_grounded_by_the_tick_watchdog() -> None:
    """set_mode: "Selecting a stepping mode re-arms an axis grounded by a watchdog" (a host
    speaking only a real ANC300's verbs has no ``clrf``)."""
    fw = Firmware(FirmwareConfig(watchdog_s=0.05))
    clock = LateClock(3, 0.2)
    running_axis(fw)
    fw.run(clock, max_ticks=5)
    axis = fw.axis(1)
    assert axis.status().faults == ("watchdog",)
    axis.set_mode("stp")
    assert axis.status().fault_word == 0 and axis.status().mode == "stp"
    axis.step(3)
    fw.run(clock, max_ticks=150)
    assert axis.status().step_counter >= 3 and not axis.status().moving


@pytest.mark.parametrize("mode", ["stp", "stp+", "stp-"])
def test_a_real_anc300_setm_rearms_after_a_host_watchdog(mode: str) -> None:
    fw = Firmware()
    fw.axis(2).inject_fault(Fault.HOST_WATCHDOG)
    session = console(fw)
    assert reply(session, f"setm 2 {mode}") == ["OK"]
    assert reply(session, "getm 2") == [f"mode = {mode}", "OK"]
    assert fw.axis(2).status().fault_word == 0


def test_a_stepping_mode_does_not_rearm_an_overtemperature() -> None:
    fw = Firmware()
    axis = fw.axis(1)
    axis.inject_fault(Fault.WATCHDOG)
    axis.inject_fault(Fault.OVERTEMP)
    with pytest.raises(FirmwareError, match="fault"):
        axis.set_mode("stp")
    assert axis.status().faults == ("watchdog", "overtemp")


# -- value ranges -------------------------------------------------------------------------------


def test_an_offset_above_the_rail_is_refused() -> None:
    fw = Firmware()  # rails 0 … 200 V
    axis = fw.axis(1)
    axis.set_offset(200.0)  # on the rail: allowed
    for volts in (200.5, 249.0):
        with pytest.raises(LimitError) as err:
            axis.set_offset(volts)
        assert (err.value.field, err.value.lo, err.value.hi) == ("offset", 0.0, 200.0)
    assert axis.status().offset_v == 200.0


def test_seta_above_the_rail_answers_the_range_and_error() -> None:
    fw = Firmware()
    session = console(fw)
    assert reply(session, "seta 1 12.5") == ["OK"]
    assert reply(session, "seta 1 200.5") == ["Value out of range: offset = 200.5 not in [0, 200]", "ERROR"]
    assert reply(session, "geta 1") == ["voltage = 12.500000 V", "OK"]


@pytest.mark.parametrize("count", [I32_MAX + 1, -(I32_MAX + 1), 2 * I32_MAX])
def test_a_burst_longer_than_the_i32_step_range_is_refused(count: int) -> None:
    fw = Firmware()
    axis = fw.axis(1)
    axis.set_mode("stp")
    with pytest.raises(LimitError) as err:
        axis.step(count)
    assert (err.value.field, err.value.lo, err.value.hi) == ("steps", 1, I32_MAX)
    assert not axis.status().moving


def test_the_longest_burst_is_accepted_and_one_more_step_is_refused_on_the_console() -> None:
    fw = Firmware()
    session = console(fw)
    assert reply(session, "setm 1 stp") == ["OK"]
    assert reply(session, f"stepu 1 {I32_MAX + 1}") == [
        f"Value out of range: steps = {I32_MAX + 1} not in [1, {I32_MAX}]",
        "ERROR",
    ]
    assert not fw.axis(1).status().moving
    assert reply(session, f"stepd 1 {I32_MAX}") == ["OK"]
    assert fw.axis(1).status().moving
    assert reply(session, "stop 1") == ["OK"]
