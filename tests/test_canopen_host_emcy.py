"""The host driver listens to the node's EMCY: logged, remembered per axis, raised by the axis'
next step or a wait in progress, cleared by an error reset.  Against firmware_sim's node (which
sends EMCY when a fault latches) on python-can's ``virtual`` bus.
"""

from __future__ import annotations

import logging
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import can
import pytest

from feeder.daemon.executor import AmplifierExecutor
from feeder.daemon.jobs import Command, Completion, StepMode
from feeder.drivers.amplifier import AmplifierError, AmplifierLinkLost, DriveSettings
from feeder.drivers.canopen import CanopenAmplifier, open_node_axes
from feeder.protocol.eds import EDS_3AXIS_FILE, object_dictionary
from firmware_sim.canopen_node import CanopenNode
from firmware_sim.clock import RealTimeClock
from firmware_sim.faults import Fault
from firmware_sim.firmware import Firmware, FirmwareConfig

pytestmark = pytest.mark.timeout(60)
NODE_ID = 6
HEARTBEAT_S = 0.2
FAST = DriveSettings(frequency_hz=1000.0, amplitude_v=40.0, flyback_shape="linear", flyback_s=100e-6)


@dataclass
class Rig:
    firmware: Firmware
    nodes: list[CanopenNode]
    channel: str


def start(axes: int, per_node: int) -> Iterator[Rig]:
    channel = f"test-canopen-host-emcy-{uuid.uuid4().hex}"
    firmware = Firmware(FirmwareConfig(axes=axes, watchdog_s=5.0))  # in-process: CI stalls its tick
    stop = threading.Event()
    ticker = threading.Thread(target=firmware.run, args=(RealTimeClock(), stop), daemon=True)
    ticker.start()
    od = object_dictionary(NODE_ID, EDS_3AXIS_FILE) if per_node == 3 else None
    numbers = range(1, per_node + 1) if per_node > 1 else 1
    node = CanopenNode(firmware, numbers, NODE_ID, can.Bus(interface="virtual", channel=channel), od=od)
    yield Rig(firmware, [node.start()], channel)
    node.close()
    stop.set()
    ticker.join(timeout=2.0)


@pytest.fixture
def rig() -> Iterator[Rig]:
    yield from start(1, 1)


@pytest.fixture
def rig3() -> Iterator[Rig]:
    yield from start(3, 3)


@pytest.fixture
def amp(rig: Rig) -> Iterator[CanopenAmplifier]:
    bus = {"interface": "virtual", "channel": rig.channel}
    driver = CanopenAmplifier(bus, NODE_ID, heartbeat_s=HEARTBEAT_S, timeout_s=0.5)
    yield driver
    driver.close()


def wait_until(condition: Callable[[], object], timeout_s: float = 3.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.005)
    assert condition(), "timed out"


def test_a_fault_during_a_burst_ends_the_wait_with_the_emcy(rig: Rig, amp: CanopenAmplifier) -> None:
    """A latched host watchdog grounds the axis: without EMCY the wait would see a burst that
    just ended early (a stall); with it, the wait raises the node's reason at once."""
    axis = rig.firmware.axis(1)
    amp.apply(FAST)
    amp.enable()
    amp.step(100_000)  # 100 s at 1 kHz
    timer = threading.Timer(0.2, axis.inject_fault, args=(Fault.HOST_WATCHDOG,))
    timer.start()
    started = time.monotonic()
    with pytest.raises(AmplifierError, match=r"CANopen node 6: EMCY 0x8130 host watchdog on axis 1") as err:
        amp.wait(10.0)
    assert not isinstance(err.value, AmplifierLinkLost)
    assert time.monotonic() - started < 2.0
    timer.join()


def test_the_next_step_raises_the_emcy_once_and_it_is_logged(
    rig: Rig, amp: CanopenAmplifier, caplog: pytest.LogCaptureFixture
) -> None:
    amp.apply(FAST)
    amp.enable()
    with caplog.at_level(logging.WARNING, logger="feeder.drivers.canopen_link"):
        rig.firmware.axis(1).inject_fault(Fault.OVERTEMP)
        wait_until(lambda: amp.emcy is not None)
    assert amp.emcy == "CANopen node 6: EMCY 0x4200 over-temperature on axis 1"
    assert any("EMCY 0x4200 over-temperature on axis 1" in r.message for r in caplog.records)
    with pytest.raises(AmplifierError, match="EMCY 0x4200 over-temperature on axis 1"):
        amp.step(10)
    # raised once: the node's own refusal speaks from then on; the EMCY stays remembered
    with pytest.raises(AmplifierError, match=r"refused \(fault overtemp\)"):
        amp.step(10)
    assert amp.emcy is not None
    amp.stop()  # a stop never raises an EMCY
    amp.clear_faults()
    assert amp.emcy is None
    amp.enable()
    amp.step(5)
    assert amp.wait(5.0)


def test_an_error_reset_clears_the_emcy(rig: Rig, amp: CanopenAmplifier) -> None:
    axis = rig.firmware.axis(1)
    amp.apply(FAST)
    amp.enable()
    axis.inject_fault(Fault.WATCHDOG)
    wait_until(lambda: amp.emcy is not None)
    assert "EMCY 0x6010 tick watchdog" in str(amp.emcy)
    axis.clear_faults()  # not by the driver: the node sends EMCY 0x0000 (error reset)
    wait_until(lambda: amp.emcy is None)
    with pytest.raises(AmplifierError, match=r"refused \(mode gnd\)"):  # no stale EMCY
        amp.step(5)
    amp.enable()
    amp.step(5)
    assert amp.wait(5.0)


def test_an_error_reset_naming_no_axis_clears_only_once_the_register_is_clear(
    rig: Rig, amp: CanopenAmplifier
) -> None:
    """CANopenNode's EMCY 0x0000 as one of several errors clears (byte 7 its own: 0): the
    error register it carries still set keeps the axis' EMCY; a register of 0 clears it."""
    amp.apply(FAST)
    amp.enable()
    rig.firmware.axis(1).inject_fault(Fault.OVERTEMP)
    wait_until(lambda: amp.emcy is not None)
    with can.Bus(interface="virtual", channel=rig.channel) as other:
        other.send(
            can.Message(
                arbitration_id=0x80 + NODE_ID, data=bytes([0, 0, 0x09, 0, 0, 0, 0, 0]), is_extended_id=False
            )
        )
        time.sleep(0.3)
        assert "EMCY 0x4200 over-temperature on axis 1" in str(amp.emcy)
        other.send(can.Message(arbitration_id=0x80 + NODE_ID, data=bytes(8), is_extended_id=False))
        wait_until(lambda: amp.emcy is None)


def test_the_executor_ends_the_burst_as_a_refused_command(rig: Rig, amp: CanopenAmplifier) -> None:
    """The daemon's side: confirm_end completes with the EMCY as its error, not a lost link."""
    mode = StepMode("coarse", FAST, 1e-6, (0.5e-6, 1.5e-6))
    executor = AmplifierExecutor(amp, {"x": {"coarse": mode}})
    try:
        for command in (Command("enable"), Command("apply", mode="coarse"), Command("step", steps=100_000)):
            executor.submit(command)
        executor.submit(Command("confirm_end", timeout_s=30.0))
        wait_until(lambda: rig.firmware.axis(1).status().moving)
        rig.firmware.axis(1).inject_fault(Fault.HOST_WATCHDOG)
        completions: list[Completion] = []

        def four_done() -> bool:
            completions.extend(executor.take())
            return len(completions) == 4

        wait_until(four_done, 5.0)
        confirm = completions[-1]
        assert confirm.command.kind == "confirm_end"
        assert confirm.error is not None and "EMCY 0x8130 host watchdog on axis 1" in confirm.error
        assert not confirm.link_lost
    finally:
        executor.close()


def test_on_a_three_axis_node_only_the_named_axis_raises(rig3: Rig) -> None:
    amps = open_node_axes(
        {"interface": "virtual", "channel": rig3.channel},
        NODE_ID,
        eds=object_dictionary(NODE_ID, EDS_3AXIS_FILE),
        heartbeat_s=HEARTBEAT_S,
        timeout_s=0.5,
    )
    try:
        for each in amps.values():
            each.apply(FAST)
            each.enable()
        rig3.firmware.axis(2).inject_fault(Fault.OVERTEMP)
        wait_until(lambda: amps[2].emcy is not None)
        assert amps[1].emcy is None and amps[3].emcy is None
        amps[1].step(5)
        assert amps[1].wait(5.0)
        with pytest.raises(AmplifierError, match="node 6: EMCY 0x4200 over-temperature on axis 2"):
            amps[2].step(5)
    finally:
        for each in amps.values():
            each.close()
