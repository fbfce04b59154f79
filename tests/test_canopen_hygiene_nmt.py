"""The simulated node's NMT and fault rules over CAN (docs/canopen.md, *Behaviour*):

- motion starts in OPERATIONAL only: outside it, an SDO write that would start motion
  (``Step command`` or ``Continuous`` not 0) aborts with 0x08000022; stopping and
  grounding stay allowed;
- NMT commands other than CiA 301's five are ignored;
- a ``Mode`` write re-arms an axis whose only latched faults are the watchdogs
  (``watchdog``, ``host_watchdog``) when it selects a stepping mode, as the console's
  ``setm`` does; any other latched fault needs ``Fault reset``.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass

import can
import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError
from test_canopen_hygiene_event_timer import ticking_firmware

from feeder.drivers.canopen import open_node_axes
from feeder.protocol.eds import EDS_3AXIS_FILE, MODES, axis_count, object_dictionary
from firmware_sim.canopen_node import EMCY_CODES, CanopenNode
from firmware_sim.faults import Fault
from firmware_sim.firmware import Firmware

pytestmark = pytest.mark.timeout(60)
NODE_ID = 3
DEVICE_STATE = 0x08000022


@dataclass
class Rig:
    firmware: Firmware
    node: CanopenNode
    master: canopen.RemoteNode
    network: canopen.Network
    channel: str
    eds: str

    def refused(self, name: str, value: int) -> None:
        """Writing ``value`` to ``name`` aborts with 0x08000022."""
        with pytest.raises(SdoAbortedError) as info:
            self.master.sdo[name].raw = value
        assert info.value.code == DEVICE_STATE

    def moving(self, axis: int = 1) -> bool:
        return self.firmware.axis(axis).status().moving


@pytest.fixture(params=["feeder_amplifier.eds", EDS_3AXIS_FILE])
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    """A ticking firmware's axes as node :data:`NODE_ID` (one- or three-axis EDS) on a
    virtual bus, with a plain canopen master; the axes' settings allow stepping."""
    od = object_dictionary(NODE_ID, request.param)
    axes = list(range(1, axis_count(od) + 1))
    with ticking_firmware() as (firmware, channel):
        node = CanopenNode(firmware, axes, NODE_ID, can.Bus(interface="virtual", channel=channel), od=od)
        network = canopen.Network()
        network.NOTIFIER_CYCLE = 0.1
        network.connect(interface="virtual", channel=channel)
        master = canopen.RemoteNode(NODE_ID, object_dictionary(NODE_ID, request.param))
        master.sdo.RESPONSE_TIMEOUT = 1.0
        network.add_node(master)
        node.start()
        try:
            yield Rig(firmware, node, master, network, channel, request.param)
        finally:
            network.disconnect()
            node.close()


def axis_name(rig: Rig, name: str, axis: int = 1) -> str:
    """Axis ``axis``' object ``name`` in the rig's EDS."""
    return name if len(rig.node.ports) == 1 else f"Axis {axis} {name}"


# -- motion only in OPERATIONAL ----------------------------------------------------------------


@pytest.mark.parametrize("state", ["booted", "PRE-OPERATIONAL"])
def test_sdo_writes_that_start_motion_are_refused_outside_operational(rig: Rig, state: str) -> None:
    """After boot-up, and after NMT enter-pre-operational (0x80) from OPERATIONAL."""
    axis = len(rig.node.ports)  # the last axis: "Axis 3 ..." on the three-axis node
    name = lambda base: axis_name(rig, base, axis)  # noqa: E731
    rig.master.sdo[name("Mode")].raw = MODES.index("stp")
    if state != "booted":
        rig.master.nmt.state = "OPERATIONAL"
        rig.master.nmt.state = state
        rig.master.sdo[name("Mode")].raw  # noqa: B018 (the node has handled the NMT commands)
    assert rig.node.nmt_state == 127
    counter = rig.firmware.axis(axis).status().step_counter
    rig.refused(name("Continuous"), 1)
    rig.refused(name("Continuous"), -1)
    rig.refused(name("Step command"), 10)
    rig.refused(name("Step command"), -10)
    time.sleep(0.05)
    status = rig.firmware.axis(axis).status()
    assert not status.moving and status.step_counter == counter
    assert rig.master.sdo[name("Step command")].raw == 0  # a refused write changes nothing
    # stopping and grounding stay allowed
    rig.master.sdo[name("Continuous")].raw = 0
    rig.master.sdo[name("Step command")].raw = 0
    rig.master.sdo[name("Mode")].raw = MODES.index("gnd")
    assert rig.firmware.axis(axis).status().mode == "gnd"


def test_the_same_writes_start_motion_in_operational(rig: Rig) -> None:
    name = lambda base: axis_name(rig, base)  # noqa: E731
    rig.master.sdo[name("Mode")].raw = MODES.index("stp")
    rig.master.nmt.state = "OPERATIONAL"
    rig.master.sdo[name("Continuous")].raw = 1
    assert rig.moving()
    rig.master.sdo[name("Continuous")].raw = 0
    rig.master.sdo[name("Step command")].raw = 5
    assert rig.moving()


def test_the_driver_starts_motion_only_once_the_node_is_operational(rig: Rig) -> None:
    """The host driver never needs motion in PRE-OPERATIONAL: it starts the node first."""
    bus = {"interface": "virtual", "channel": rig.channel}
    amps = list(
        open_node_axes(bus, NODE_ID, eds=object_dictionary(NODE_ID, rig.eds), heartbeat_s=0.5).values()
    )
    try:
        for amp in amps:
            amp.enable()
            amp.run_continuous(forward=True)
        assert all(rig.moving(axis) for axis in range(1, len(amps) + 1))
        for amp in amps:
            amp.stop()
            amp.step(3)
            assert amp.wait(5.0)
    finally:
        for amp in amps:
            amp.close()


# -- NMT commands --------------------------------------------------------------------------------


@pytest.mark.parametrize("command", [0x00, 0x03, 0x50, 0x60, 0x7F, 0x83, 0xFF])
def test_nmt_commands_cia_301_lacks_are_ignored(rig: Rig, command: int) -> None:
    name = lambda base: axis_name(rig, base)  # noqa: E731
    rig.master.sdo[name("Mode")].raw = MODES.index("stp")
    rig.master.nmt.state = "OPERATIONAL"
    rig.master.sdo[name("Continuous")].raw = 1
    rig.network.send_message(0x000, bytes([command, NODE_ID]))
    rig.network.send_message(0x000, bytes([command, 0]))
    rig.master.sdo[name("Mode")].raw  # noqa: B018 (the node has handled the NMT commands)
    assert rig.master.nmt.wait_for_heartbeat(2.0) == "OPERATIONAL"
    assert rig.node.nmt_state == 5
    assert rig.moving()  # not stopped either


# -- faults: what a Mode write re-arms, what needs Fault reset ------------------------------------


def wait_emcy(rig: Rig, code: int) -> None:
    """Until the master has received an EMCY with ``code`` (fails after 3 s)."""
    deadline = time.monotonic() + 3.0
    while code not in [emcy.code for emcy in rig.master.emcy.log]:
        assert time.monotonic() < deadline, f"no EMCY 0x{code:04X}"
        time.sleep(0.01)


@pytest.mark.parametrize("fault", [Fault.WATCHDOG, Fault.HOST_WATCHDOG])
@pytest.mark.parametrize("mode", ["stp", "stp+", "stp-"])
def test_a_stepping_mode_rearms_an_axis_whose_only_faults_are_the_watchdogs(
    rig: Rig, fault: Fault, mode: str
) -> None:
    name = lambda base: axis_name(rig, base)  # noqa: E731
    rig.firmware.axis(1).inject_fault(fault)
    rig.firmware.axis(1).inject_fault(Fault.WATCHDOG)  # both watchdogs, or the one
    wait_emcy(rig, EMCY_CODES[fault])  # the node reported the fault
    rig.refused(name("Mode"), MODES.index("off"))  # any other mode but gnd: refused, nothing cleared
    rig.refused(name("Mode"), MODES.index("inp"))
    assert rig.master.sdo[name("Fault word")].raw == fault | Fault.WATCHDOG
    rig.master.emcy.reset()
    rig.master.sdo[name("Mode")].raw = MODES.index(mode)  # the console's setm re-arms alike
    assert rig.master.sdo[name("Fault word")].raw == 0
    assert rig.master.sdo[name("Mode")].raw == MODES.index(mode)
    wait_emcy(rig, 0x0000)  # the error reset tells the host


@pytest.mark.parametrize("others", [Fault.OVERTEMP, Fault.OVERTEMP | Fault.HOST_WATCHDOG])
def test_any_other_fault_refuses_every_mode_but_gnd_until_fault_reset(rig: Rig, others: Fault) -> None:
    name = lambda base: axis_name(rig, base)  # noqa: E731
    for bit in Fault:
        if others & bit:
            rig.firmware.axis(1).inject_fault(bit)
    for mode in ("stp", "stp+", "stp-", "off", "inp"):
        rig.refused(name("Mode"), MODES.index(mode))
    assert rig.master.sdo[name("Fault word")].raw == others  # a refused write clears nothing
    rig.master.sdo[name("Mode")].raw = MODES.index("gnd")  # grounding: always
    rig.master.sdo[name("Fault reset")].raw = 1
    assert rig.master.sdo[name("Fault word")].raw == 0
    assert rig.master.sdo[name("Mode")].raw == MODES.index("gnd")  # the output stays grounded
    rig.master.sdo[name("Mode")].raw = MODES.index("stp")
