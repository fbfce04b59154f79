"""CiA 301 frames only: 29-bit (extended-ID) and remote frames reach neither the simulated
node nor the host driver, whatever identifier they carry (docs/canopen.md, *Behaviour*).

The node is tried on both of its receive paths: firmware_sim's CAN wire (frames handled in
the sender's thread) and python-can's ``virtual`` bus (``network.connect()``).  A frame the
node handles in order after the injected ones (an SDO request, or a sentinel on the host)
proves the injected ones were seen, and ignored.
"""

from __future__ import annotations

import contextlib
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, cast

import can
import canopen
import pytest

from feeder.drivers.axes import open_canopen_axes
from feeder.drivers.canopen import CanopenAmplifier
from feeder.protocol.eds import MODES, object_dictionary
from firmware_sim.can_wire import CanWire
from firmware_sim.canopen_node import CanopenNode
from firmware_sim.clock import RealTimeClock
from firmware_sim.faults import Fault
from firmware_sim.firmware import Firmware, FirmwareConfig

pytestmark = pytest.mark.timeout(60)
NODE_ID = 1
HOST_ID = 127
SENTINEL_ID = 0x6E0
"""An identifier nobody uses: the host test's marker that earlier frames were processed."""


@contextlib.contextmanager
def ticking_firmware() -> Iterator[Firmware]:
    """A firmware ticking in real time (its watchdog generous: the test machine is shared)."""
    firmware = Firmware(FirmwareConfig(watchdog_s=5.0))
    stop = threading.Event()
    ticker = threading.Thread(target=firmware.run, args=(RealTimeClock(), stop), daemon=True)
    ticker.start()
    try:
        yield firmware
    finally:
        stop.set()
        ticker.join(timeout=2.0)


# -- the node -------------------------------------------------------------------------------


@dataclass
class NodeRig:
    firmware: Firmware
    node: CanopenNode
    master: canopen.RemoteNode
    network: canopen.Network

    def inject(self, can_id: int, data: bytes = b"", *, extended: bool = False, remote: bool = False) -> None:
        """Put one raw frame on the bus, as another device would."""
        message = can.Message(
            arbitration_id=can_id,
            data=data,
            is_extended_id=extended,
            is_remote_frame=remote,
            dlc=len(data) or 5,
        )
        assert self.network.bus is not None
        self.network.bus.send(message)

    def settle(self) -> None:
        """Return once the node handled every frame injected so far (it answers in order)."""
        self.master.sdo["Device type"].raw  # noqa: B018 (the request is the point)


@pytest.fixture(params=["wire", "virtual"])
def node_rig(request: pytest.FixtureRequest) -> Iterator[NodeRig]:
    """A node on firmware_sim's CAN wire or on a ``virtual`` bus, with a plain canopen master."""
    with ticking_firmware() as firmware:
        network = canopen.Network()
        network.NOTIFIER_CYCLE = 0.1
        if request.param == "wire":
            wire = CanWire()
            node = CanopenNode(firmware, 1, NODE_ID, wire.bus())
            network.bus = wire.bus(lambda m: network.notify(m.arbitration_id, m.data, m.timestamp))
        else:
            channel = f"test-canopen-hygiene-{uuid.uuid4().hex}"
            node = CanopenNode(firmware, 1, NODE_ID, can.Bus(interface="virtual", channel=channel))
            network.connect(interface="virtual", channel=channel)
        master = canopen.RemoteNode(NODE_ID, object_dictionary(NODE_ID))
        master.sdo.RESPONSE_TIMEOUT = 1.0
        network.add_node(master)
        node.start()
        try:
            yield NodeRig(firmware, node, master, network)
        finally:
            node.close()
            network.disconnect()


def test_an_extended_nmt_command_changes_no_state(node_rig: NodeRig) -> None:
    node_rig.inject(0x000, bytes([0x01, 0x00]), extended=True)  # "start all nodes", 29-bit
    node_rig.settle()
    assert node_rig.node.nmt_state == 127  # still PRE-OPERATIONAL
    node_rig.master.nmt.state = "OPERATIONAL"
    node_rig.inject(0x000, bytes([0x80, NODE_ID]), extended=True)  # "enter PRE-OPERATIONAL"
    node_rig.inject(0x000, bytes([0x81, NODE_ID]), extended=True)  # "reset node"
    node_rig.settle()
    assert node_rig.node.nmt_state == 5  # still OPERATIONAL, not rebooted


def test_an_extended_sdo_request_gets_no_answer(node_rig: NodeRig) -> None:
    answers: list[bytes] = []
    node_rig.network.subscribe(0x580 + NODE_ID, lambda can_id, data, ts: answers.append(bytes(data)))
    node_rig.inject(0x600 + NODE_ID, bytes([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]), extended=True)  # Frequency
    node_rig.settle()
    assert len(answers) == 1  # the settling request's answer only


@pytest.mark.parametrize(("extended", "remote"), [(True, False), (False, True)], ids=["extended", "remote"])
def test_an_extended_or_remote_rpdo_starts_nothing_and_raises_no_emcy(
    node_rig: NodeRig, extended: bool, remote: bool
) -> None:
    sdo = node_rig.master.sdo
    sdo["Mode"].raw = MODES.index("stp")
    node_rig.master.nmt.state = "OPERATIONAL"
    node_rig.settle()
    node_rig.master.emcy.reset()
    data = b"" if remote else bytes([0x19, 0x00, 0x00, 0x00, 0x07])  # 25 steps, sequence 7
    node_rig.inject(0x200 + NODE_ID, data, extended=extended, remote=remote)
    node_rig.settle()
    assert not node_rig.firmware.axis(1).status().moving
    assert sdo["Command acknowledge"].raw == 0
    assert sdo["Step command"].raw == 0
    assert [e.code for e in node_rig.master.emcy.log] == []  # no 0x8210 for a "short RPDO"


@pytest.mark.parametrize(("extended", "remote"), [(True, False), (False, True)], ids=["extended", "remote"])
def test_extended_or_remote_host_heartbeats_do_not_feed_the_consumer(
    node_rig: NodeRig, extended: bool, remote: bool
) -> None:
    """Once the host's real heartbeat stops, the moving axis is grounded however many
    29-bit or remote frames carry the host's heartbeat identifier."""
    sdo = node_rig.master.sdo
    sdo["Consumer heartbeat time"][1].raw = HOST_ID << 16 | 100  # 100 ms
    node_rig.inject(0x700 + HOST_ID, bytes([0x05]))  # one real beat: monitoring starts
    sdo["Mode"].raw = MODES.index("stp")
    node_rig.master.nmt.state = "OPERATIONAL"
    sdo["Continuous"].raw = 1
    deadline = time.monotonic() + 0.6
    while time.monotonic() < deadline:
        node_rig.inject(0x700 + HOST_ID, b"" if remote else bytes([0x05]), extended=extended, remote=remote)
        time.sleep(0.02)
    status = node_rig.firmware.axis(1).status()
    assert status.fault_word & Fault.HOST_WATCHDOG
    assert not status.moving


# -- the host driver --------------------------------------------------------------------------


@contextlib.contextmanager
def sim_nodes(*node_ids: int) -> Iterator[dict[str, Any]]:
    """Axis n of a ticking firmware as node ``node_ids[n - 1]`` on a fresh virtual channel;
    yields the host's bus arguments."""
    channel = f"test-canopen-hygiene-{uuid.uuid4().hex}"
    with ticking_firmware() as firmware, contextlib.ExitStack() as stack:
        for axis, node_id in enumerate(node_ids, start=1):
            bus = can.Bus(interface="virtual", channel=channel)
            stack.enter_context(CanopenNode(firmware, axis, node_id, bus))
        yield {"interface": "virtual", "channel": channel}


def inject_then_settle(network: canopen.Network, bus: dict[str, Any], frames: list[can.Message]) -> None:
    """Send ``frames`` from another device, then a sentinel; return once the host's receiver
    has handled the sentinel (and so every frame before it)."""
    seen = threading.Event()
    network.subscribe(SENTINEL_ID, lambda can_id, data, ts: seen.set())
    other = can.Bus(**bus)
    try:
        for frame in [*frames, can.Message(arbitration_id=SENTINEL_ID, data=b"", is_extended_id=False)]:
            other.send(frame)
        assert seen.wait(5.0)
    finally:
        other.shutdown()
        network.unsubscribe(SENTINEL_ID)


def fake_frames(node_id: int) -> list[can.Message]:
    """29-bit frames whose low bits are node ``node_id``'s EMCY (host watchdog on axis 1)
    and heartbeat (STOPPED)."""
    emcy = bytes([0x30, 0x81, 0x11, 0x02, 0x00, 0x00, 0x00, 0x01])
    return [
        can.Message(arbitration_id=0x80 + node_id, data=emcy, is_extended_id=True),
        can.Message(arbitration_id=0x700 + node_id, data=bytes([0x04]), is_extended_id=True),
    ]


def test_the_driver_ignores_29_bit_frames_with_its_nodes_identifiers() -> None:
    with sim_nodes(NODE_ID) as bus:
        amp = CanopenAmplifier(bus, NODE_ID, heartbeat_s=0.5)
        try:
            inject_then_settle(amp.network, bus, fake_frames(NODE_ID))
            assert amp.emcy is None
            assert amp.lost is None
            amp.enable()
            amp.step(5)  # no EMCY raised
            assert amp.wait(5.0)
        finally:
            amp.close()


def test_a_users_can_filters_are_kept_and_29_bit_frames_still_ignored() -> None:
    """``can_filters`` in the bus arguments go to python-can as given; the driver drops
    29-bit frames after them, in its listener."""
    with sim_nodes(NODE_ID) as base:
        filters = [{"can_id": 0x000, "can_mask": 0x000}]  # the user's: every frame, both formats
        bus = {**base, "can_filters": filters}
        amp = CanopenAmplifier(bus, NODE_ID, heartbeat_s=0.5)
        try:
            assert amp.network.bus is not None and amp.network.bus.filters == filters
            inject_then_settle(amp.network, base, fake_frames(NODE_ID))
            assert amp.emcy is None
            assert amp.lost is None
        finally:
            amp.close()


def test_a_network_shared_by_several_nodes_ignores_29_bit_frames_once() -> None:
    with sim_nodes(NODE_ID, NODE_ID + 1) as bus:
        axes = open_canopen_axes(bus, {"x": 1, "y": 2}, node_id=NODE_ID, heartbeat_s=0.5)
        try:
            drivers = [axes[name] for name in ("x", "y")]
            assert all(isinstance(driver, CanopenAmplifier) for driver in drivers)
            amps = cast(list[CanopenAmplifier], drivers)
            network = amps[0].network
            assert network.notifier is not None
            inject_then_settle(network, bus, fake_frames(NODE_ID) + fake_frames(NODE_ID + 1))
            assert [amp.lost for amp in amps] == [None, None]
            assert [amp.emcy for amp in amps] == [None, None]
            kinds = [type(listener).__name__ for listener in network.notifier.listeners]
            assert kinds.count("CanopenFrames") == 1 and "MessageListener" not in kinds  # one, not two
        finally:
            axes.close()
