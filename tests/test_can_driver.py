"""The host's CANopen driver against the firmware_sim node, over ``virtual`` and slcan-pty.

The firmware ticks in real time in a thread; its own counters and settings are
the reference the driver's view is checked against.
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import can
import canopen
import pytest

from feeder.drivers.amplifier import AmplifierError, AmplifierLinkLost, DriveSettings
from feeder.drivers.canopen import CanopenAmplifier, fault_names
from firmware_sim.axis import fault_names as firmware_fault_names
from firmware_sim.canopen_node import CanopenNode
from firmware_sim.clock import RealTimeClock
from firmware_sim.faults import Fault
from firmware_sim.firmware import Firmware, FirmwareConfig
from firmware_sim.slcan import SlcanPty

pytestmark = pytest.mark.timeout(60)
NODE_ID = 4
HEARTBEAT_S = 0.2  # generous: a loaded test machine can starve threads
FAST = DriveSettings(frequency_hz=1000.0, amplitude_v=40.0, flyback_shape="linear", flyback_s=100e-6)


@dataclass
class Rig:
    firmware: Firmware
    node: CanopenNode
    amp: CanopenAmplifier
    channel: str


@pytest.fixture(params=["virtual", "slcan-pty"])
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    channel = f"test-can-driver-{uuid.uuid4().hex}"
    firmware = Firmware(FirmwareConfig(watchdog_s=5.0))  # in-process: a loaded CI stalls its tick
    stop = threading.Event()
    ticker = threading.Thread(target=firmware.run, args=(RealTimeClock(), stop), daemon=True)
    ticker.start()
    node = CanopenNode(firmware, 2, NODE_ID, can.Bus(interface="virtual", channel=channel))
    node.start()
    adapter = None
    bus: dict[str, Any] = {"interface": "virtual", "channel": channel}
    if request.param == "slcan-pty":
        adapter = SlcanPty(can.Bus(interface="virtual", channel=channel)).start()
        bus = {"interface": "slcan", "channel": adapter.path, "bitrate": 500000, "sleep_after_open": 0}
    amp = CanopenAmplifier(bus, NODE_ID, heartbeat_s=HEARTBEAT_S, timeout_s=0.5, supervise_host=True)
    yield Rig(firmware, node, amp, channel)
    amp.close()
    if node.network.bus is not None:
        node.close()
    if adapter is not None:
        adapter.close()
    stop.set()
    ticker.join(timeout=2.0)


def test_fault_names_agree_with_the_firmware() -> None:
    for word in (0, 1, 2, 4, 7, 5):
        assert fault_names(word) == firmware_fault_names(word)


def test_apply_enable_step_and_wait(rig: Rig) -> None:
    amp, axis = rig.amp, rig.firmware.axis(2)
    amp.apply(FAST)
    amp.enable()
    status = axis.status()
    assert (status.frequency_hz, status.amplitude_v) == (1000.0, 40.0)
    assert (status.flyback_shape, status.flyback_s, status.mode) == ("linear", pytest.approx(100e-6), "stp")
    amp.step(120)
    assert amp.wait(3.0)
    assert axis.status().step_counter == 120 == amp.step_counter
    amp.step(-45)
    assert amp.wait(3.0)
    reported = amp.status()
    assert reported.step_counter == axis.status().step_counter == 75
    assert (reported.mode, reported.moving, reported.fault_word) == ("stp", False, 0)
    assert (reported.frequency_hz, reported.amplitude_v) == (1000.0, 40.0)


def test_apply_reorders_flyback_and_frequency_as_needed(rig: Rig) -> None:
    axis = rig.firmware.axis(2)
    slow_long = DriveSettings(
        frequency_hz=50.0, amplitude_v=10.0, flyback_shape="half-cosine", flyback_s=15e-3
    )
    for settings in (FAST, slow_long, FAST):
        rig.amp.apply(settings)
        status = axis.status()
        assert (status.frequency_hz, status.flyback_shape) == (settings.frequency_hz, settings.flyback_shape)
        assert status.flyback_s == pytest.approx(settings.flyback_s)


def test_refusals_raise_and_change_nothing(rig: Rig) -> None:
    amp, axis = rig.amp, rig.firmware.axis(2)
    amp.apply(FAST)
    before = axis.status()
    with pytest.raises(AmplifierError, match="Amplitude = 250000: value too high"):
        amp.apply(DriveSettings(frequency_hz=1000.0, amplitude_v=250.0))
    with pytest.raises(AmplifierError, match="0x06090031"):
        amp.apply(DriveSettings(frequency_hz=5000.0, amplitude_v=10.0))
    assert axis.status() == before
    with pytest.raises(AmplifierError, match=r"refused \(mode gnd\)"):
        amp.step(10)
    with pytest.raises(AmplifierError):
        amp.step(0)
    assert not axis.status().moving
    # the link is still fine after refusals
    amp.enable()
    amp.step(3)
    assert amp.wait(2.0)


def test_continuous_and_stop(rig: Rig) -> None:
    amp, axis = rig.amp, rig.firmware.axis(2)
    amp.apply(FAST)
    amp.enable()
    amp.run_continuous(forward=False)
    time.sleep(0.1)
    assert amp.status().moving
    amp.stop()
    assert amp.wait(2.0)
    counter = axis.status().step_counter
    assert counter < 0
    time.sleep(0.1)
    assert axis.status().step_counter == counter == amp.status().step_counter


def test_fault_is_reported_and_cleared(rig: Rig) -> None:
    amp, axis = rig.amp, rig.firmware.axis(2)
    amp.enable()
    axis.inject_fault(Fault.OVERTEMP)
    status = amp.status()
    assert (status.mode, status.fault_word, status.faults) == ("gnd", 4, ("overtemp",))
    with pytest.raises(AmplifierError, match="0x08000022"):
        amp.enable()
    amp.clear_faults()
    amp.enable()
    assert amp.status().faults == ()


def frames_from_host(channel: str, seconds: float, action: Any) -> list[can.Message]:
    """Frames the host puts on the bus (NMT, SDO requests, RPDO) while ``action`` runs."""
    spy = can.Bus(interface="virtual", channel=channel)
    try:
        action()
        seen: list[can.Message] = []
        deadline = time.monotonic() + seconds
        while (message := spy.recv(max(0.0, deadline - time.monotonic()))) is not None:
            if message.arbitration_id in (0x000, 0x600 + NODE_ID, 0x200 + NODE_ID):
                seen.append(message)
        return seen
    finally:
        spy.shutdown()


def expect_lost(amp: CanopenAmplifier) -> None:
    """Once lost, every call fails at once."""
    for call in (
        amp.status,
        lambda: amp.step(5),
        amp.stop,
        amp.ground,
        lambda: amp.apply(FAST),
        lambda: amp.wait(1.0),
    ):
        with pytest.raises(AmplifierLinkLost):
            call()


def test_vanished_node_is_reported_and_no_longer_commanded(rig: Rig) -> None:
    amp = rig.amp
    amp.apply(FAST)
    amp.enable()
    amp.run_continuous(forward=True)
    rig.node.close()  # no more heartbeats, no answers
    with pytest.raises(AmplifierLinkLost, match="no heartbeat"):
        amp.wait(10.0)
    assert "no heartbeat" in (amp.lost or "")
    sent = frames_from_host(rig.channel, 0.3, lambda: expect_lost(amp))
    assert sent == []


def test_node_stopped_by_nmt_is_reported(rig: Rig) -> None:
    other = canopen.Network()
    other.NOTIFIER_CYCLE = 0.1
    other.connect(interface="virtual", channel=rig.channel)
    try:
        rig.amp.enable()
        other.nmt.send_command(0x02)  # every node: STOPPED
        deadline = time.monotonic() + 5.0
        while rig.amp.lost is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert "reported NMT state STOPPED" in (rig.amp.lost or "")
        expect_lost(rig.amp)
    finally:
        other.disconnect()


def test_a_node_that_left_operational_and_drives_on_is_grounded_by_sdo(
    rig: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Another master puts the node in PRE-OPERATIONAL; unlike our simulated node, a real drive
    may keep its axis running (CiA 301 does not stop outputs on a state change).  The link is
    lost and refuses steps, but ``ground`` reaches the node by SDO, which it still serves."""
    amp, axis = rig.amp, rig.firmware.axis(2)
    amp.apply(FAST)
    amp.enable()
    amp.run_continuous(forward=True)
    other = canopen.Network()
    other.NOTIFIER_CYCLE = 0.1
    other.connect(interface="virtual", channel=rig.channel)
    try:
        with monkeypatch.context() as drives_on:
            drives_on.setattr(axis, "stop", lambda: None)  # the state change leaves it running
            other.nmt.send_command(0x80)  # every node: PRE-OPERATIONAL
            deadline = time.monotonic() + 5.0
            while amp.lost is None and time.monotonic() < deadline:
                time.sleep(0.01)
        assert "reported NMT state PRE-OPERATIONAL" in (amp.lost or "")
        assert axis.status().moving
        with pytest.raises(AmplifierLinkLost):
            amp.step(5)
        amp.ground()
        status = axis.status()
        assert status.mode == "gnd" and not status.moving
    finally:
        other.disconnect()


def test_a_host_that_dies_mid_move_gets_the_axis_grounded(rig: Rig) -> None:
    amp, axis = rig.amp, rig.firmware.axis(2)
    amp.apply(FAST)
    amp.enable()
    amp.run_continuous(forward=True)
    assert amp._host_heartbeat is not None
    amp._host_heartbeat.stop()  # the host process froze: no more heartbeats
    deadline = time.monotonic() + 5.0
    while not axis.status().fault_word and time.monotonic() < deadline:
        time.sleep(0.01)
    status = axis.status()
    assert (status.faults, status.mode) == (("host_watchdog",), "gnd")


def test_closing_the_driver_leaves_a_moving_axis_alone(rig: Rig) -> None:
    amp, axis = rig.amp, rig.firmware.axis(2)
    amp.apply(FAST)
    amp.enable()
    amp.run_continuous(forward=True)
    amp.close()
    time.sleep(6 * HEARTBEAT_S)  # twice the node's consumer time
    status = axis.status()
    assert status.moving and status.fault_word == 0
    axis.stop()


def test_a_dead_host_bus_is_a_lost_link_not_a_can_error(rig: Rig) -> None:
    """The adapter's port vanishing under the host (e.g. firmware_sim killed) must surface as
    AmplifierLinkLost from SDO and RPDO alike, never as a python-can exception."""
    assert rig.amp.status().mode == "gnd"
    bus = rig.amp.network.bus
    assert bus is not None
    bus.shutdown()  # every send now raises can.CanOperationError
    with pytest.raises(AmplifierLinkLost):
        rig.amp.status()
    with pytest.raises(AmplifierLinkLost):
        rig.amp.step(3)


def test_hold_offset_is_the_offset_mode(rig: Rig) -> None:
    amp, axis = rig.amp, rig.firmware.axis(2)
    amp.hold_offset(12.5)
    assert (axis.status().mode, axis.status().offset_v) == ("off", 12.5)
    amp.ground()
    assert (axis.status().mode, axis.status().offset_v) == ("gnd", 0.0)  # a later offset starts at 0
    amp.hold_offset(0.25)  # grounding ended the offset mode: the driver selects it again
    assert (axis.status().mode, axis.status().offset_v) == ("off", 0.25)
    amp.ground()


@pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")
@pytest.mark.parametrize("latched", [Fault.HOST_WATCHDOG, Fault.OVERTEMP])
def test_a_node_that_refuses_operational_with_a_latched_fault(latched: Fault) -> None:
    """A node that leaves OPERATIONAL while its error register is set (CANopenNode's examples).
    A host_watchdog latched by a host before (it fell silent mid-move) is cleared on connect,
    the axis still grounded, and the driver drives it; any other fault is named when the
    start does not hold, and the failed connect leaves no host heartbeat beating."""
    channel = f"test-can-driver-{uuid.uuid4().hex}"
    firmware = Firmware(FirmwareConfig(watchdog_s=5.0))
    stop = threading.Event()
    ticker = threading.Thread(target=firmware.run, args=(RealTimeClock(), stop), daemon=True)
    ticker.start()
    bus = can.Bus(interface="virtual", channel=channel)
    node = CanopenNode(firmware, 2, NODE_ID, bus, operational_with_errors=False).start()
    axis = firmware.axis(2)
    try:
        axis.inject_fault(latched)
        options = {"heartbeat_s": HEARTBEAT_S, "timeout_s": 0.5, "supervise_host": True}
        if latched is Fault.OVERTEMP:
            with pytest.raises(
                AmplifierLinkLost, match=r"no TPDO after start \(faults latched, axis 1: overtemp"
            ):
                CanopenAmplifier({"interface": "virtual", "channel": channel}, NODE_ID, **options)
            time.sleep(3 * HEARTBEAT_S)
            assert not [t for t in threading.enumerate() if t.name.startswith("canopen-host-heartbeat")]
            return
        amp = CanopenAmplifier({"interface": "virtual", "channel": channel}, NODE_ID, **options)
        try:
            status = amp.status()
            assert (status.faults, status.mode) == ((), "gnd")
            amp.apply(FAST)
            amp.enable()
            before = status.step_counter
            amp.step(20)
            assert amp.wait(10.0) and amp.status().step_counter == before + 20
            assert amp.lost is None  # the node stayed OPERATIONAL
        finally:
            amp.close()
    finally:
        node.close()
        stop.set()
        ticker.join(timeout=2.0)
