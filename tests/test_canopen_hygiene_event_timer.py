"""The driver sets every TPDO's event timer at connect (docs/canopen.md, *What a drive must
provide*): a drive whose timer is 0 and that sends no TPDO on entering OPERATIONAL (CiA 301
asks for none) still sends its first TPDO within the driver's wait after the start.
"""

from __future__ import annotations

import contextlib
import threading
import uuid
from collections.abc import Iterator
from typing import Any

import can
import canopen
import pytest
from canopen.objectdictionary import ObjectDictionary, ODVariable

from feeder.drivers.canopen import open_node_axes
from feeder.drivers.canopen_link import TPDO_EVENT_TIMER_MS
from feeder.protocol.eds import EDS_3AXIS_FILE, EDS_FILE, axis_count, object_dictionary
from firmware_sim.canopen_node import CanopenNode
from firmware_sim.clock import RealTimeClock
from firmware_sim.firmware import Firmware, FirmwareConfig

pytestmark = pytest.mark.timeout(60)
NODE_ID = 4


def timerless_od(eds: str) -> ObjectDictionary:
    """``eds`` with every TPDO's event timer 0 by default (no periodic TPDO)."""
    od = object_dictionary(NODE_ID, eds)
    for axis in range(1, axis_count(od) + 1):
        timer = od[f"TPDO{axis} communication parameter.Event timer"]
        assert isinstance(timer, ODVariable)
        timer.default = 0
    return od


@contextlib.contextmanager
def ticking_firmware() -> Iterator[tuple[Firmware, str]]:
    """A firmware ticking in real time and a fresh virtual CAN channel's name."""
    firmware = Firmware(FirmwareConfig(watchdog_s=5.0))  # generous: the test machine is shared
    stop = threading.Event()
    ticker = threading.Thread(target=firmware.run, args=(RealTimeClock(), stop), daemon=True)
    ticker.start()
    try:
        yield firmware, f"test-canopen-hygiene-{uuid.uuid4().hex}"
    finally:
        stop.set()
        ticker.join(timeout=2.0)


@contextlib.contextmanager
def quiet_node(eds: str) -> Iterator[tuple[CanopenNode, dict[str, Any]]]:
    """Node :data:`NODE_ID` with its TPDOs' event timers 0 that sends no TPDO on entering
    OPERATIONAL, on a fresh virtual channel; yields it and the host's bus arguments."""
    od = timerless_od(eds)
    axes = list(range(1, axis_count(od) + 1))
    with ticking_firmware() as (firmware, channel):
        bus = can.Bus(interface="virtual", channel=channel)
        with CanopenNode(firmware, axes, NODE_ID, bus, od=od, tpdo_on_start=False) as node:
            yield node, {"interface": "virtual", "channel": channel}


def test_the_quiet_node_sends_no_tpdo_after_a_plain_start() -> None:
    """The double is what it claims: started by a master that sets no timer, no TPDO."""
    with quiet_node(EDS_FILE) as (_, bus):
        network = canopen.Network()
        network.NOTIFIER_CYCLE = 0.1
        network.connect(**bus)
        try:
            master = network.add_node(canopen.RemoteNode(NODE_ID, object_dictionary(NODE_ID)))
            master.tpdo.read(from_od=True)
            master.nmt.state = "OPERATIONAL"
            assert master.tpdo[1].wait_for_reception(1.0) is None
        finally:
            network.disconnect()


@pytest.mark.parametrize("eds", [EDS_FILE, EDS_3AXIS_FILE])
def test_a_node_without_a_tpdo_on_start_connects_by_the_event_timer(eds: str) -> None:
    with quiet_node(eds) as (node, bus):
        amps = open_node_axes(
            bus, NODE_ID, eds=object_dictionary(NODE_ID, eds), heartbeat_s=0.5, timeout_s=0.5
        )
        try:
            assert [port.event_timer_s for port in node.ports] == [TPDO_EVENT_TIMER_MS / 1000] * len(
                node.ports
            )
            for amp in amps.values():
                amp.enable()
                amp.step(3)
                assert amp.wait(5.0)
                assert amp.steps_played() == (3, False)
        finally:
            for amp in amps.values():
                amp.close()
