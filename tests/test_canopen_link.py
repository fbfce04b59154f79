"""The CANopen driver's connect sequence, PDO mapping check and step count, against the
firmware_sim node on python-can's ``virtual`` bus.

Nodes here differ from the EDS the host uses the way real drives do: producer heartbeat
off (0x1017 = 0, CiA 301's default on many nodes), or a PDO mapped otherwise.
"""

from __future__ import annotations

import contextlib
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import can
import canopen
import pytest
from canopen.objectdictionary import ObjectDictionary, ODRecord, ODVariable

from feeder.drivers.amplifier import AmplifierError, AmplifierLinkLost, DriveSettings
from feeder.drivers.axes import open_canopen_axes
from feeder.drivers.canopen import CanopenAmplifier
from feeder.errors import FeederError
from feeder.protocol.eds import object_dictionary
from firmware_sim.canopen_node import CanopenNode
from firmware_sim.clock import RealTimeClock
from firmware_sim.firmware import Firmware, FirmwareConfig

pytestmark = pytest.mark.timeout(60)
NODE_ID = 6
HEARTBEAT_S = 0.5  # generous: the test machine is shared, threads get starved
FAST = DriveSettings(frequency_hz=1000.0, amplitude_v=40.0, flyback_shape="linear", flyback_s=100e-6)


@contextlib.contextmanager
def sim_node(od: ObjectDictionary | None = None) -> Iterator[tuple[Firmware, CanopenNode, dict[str, Any]]]:
    """A ticking firmware's axis 1 as node :data:`NODE_ID` (dictionary ``od``) on a fresh
    virtual channel; yields the firmware, the node and the host's bus arguments."""
    channel = f"test-canopen-link-{uuid.uuid4().hex}"
    firmware = Firmware(FirmwareConfig(watchdog_s=5.0))  # in-process: a loaded CI stalls its tick
    stop = threading.Event()
    ticker = threading.Thread(target=firmware.run, args=(RealTimeClock(), stop), daemon=True)
    ticker.start()
    node = CanopenNode(firmware, 1, NODE_ID, can.Bus(interface="virtual", channel=channel), od=od)
    node.start()
    try:
        yield firmware, node, {"interface": "virtual", "channel": channel}
    finally:
        if node.network.bus is not None:
            node.close()
        stop.set()
        ticker.join(timeout=2.0)


def connect(bus: dict[str, Any]) -> CanopenAmplifier:
    return CanopenAmplifier(bus, NODE_ID, heartbeat_s=HEARTBEAT_S, timeout_s=0.5)


def silent_od() -> ObjectDictionary:
    """The EDS with the producer heartbeat off by default."""
    od = object_dictionary(NODE_ID)
    heartbeat = od["Producer heartbeat time"]
    assert isinstance(heartbeat, ODVariable)
    heartbeat.default = 0
    return od


def frames(bus: dict[str, Any], action: Callable[[], object], keep: Callable[[can.Message], bool]) -> int:
    """How many frames ``keep`` accepts on the bus while ``action`` runs (and 50 ms after)."""
    spy = can.Bus(**bus)
    try:
        action()
        seen = 0
        deadline = time.monotonic() + 0.05
        while (message := spy.recv(max(0.0, deadline - time.monotonic()))) is not None:
            seen += keep(message)
        return seen
    finally:
        spy.shutdown()


def is_heartbeat(message: can.Message) -> bool:
    return message.arbitration_id == 0x700 + NODE_ID


def is_sdo_request(message: can.Message) -> bool:
    return message.arbitration_id == 0x600 + NODE_ID


# -- connect: SDO probe, then heartbeat ------------------------------------------------------


def test_a_node_with_its_heartbeat_off_connects_and_then_beats() -> None:
    with sim_node(silent_od()) as (_, _, bus):
        assert frames(bus, lambda: time.sleep(0.3), is_heartbeat) == 0  # a booted, silent node
        amp = connect(bus)
        try:
            beats = frames(bus, lambda: time.sleep(5 * HEARTBEAT_S), is_heartbeat)
            assert 3 <= beats <= 7
            assert amp.lost is None
            assert amp.status().mode == "gnd"
        finally:
            amp.close()


def test_a_rebooted_node_whose_boot_up_was_missed_is_reconnected() -> None:
    with sim_node(silent_od()) as (_, _, bus):
        amp = connect(bus)
        master = canopen.Network()
        master.NOTIFIER_CYCLE = 0.1
        master.connect(**bus)
        try:
            master.nmt.send_command(0x81)  # reset node: boot-up frame, then silence (0x1017 = 0)
            deadline = time.monotonic() + 5.0
            while amp.lost is None and time.monotonic() < deadline:
                time.sleep(0.01)
            assert amp.lost is not None
            amp.close()
            amp = connect(bus)  # the boot-up frame is long gone
            assert amp.status().mode == "gnd"
        finally:
            amp.close()
            master.disconnect()


def test_a_node_another_master_left_stopped_is_brought_back_and_connects() -> None:
    """A STOPPED node serves no SDO: the driver sends NMT PRE-OPERATIONAL before its probe."""
    with sim_node() as (_, _, bus):
        master = canopen.Network()
        master.connect(**bus)
        try:
            master.nmt.send_command(0x02)  # stop remote node
            time.sleep(0.1)
            amp = connect(bus)
            try:
                assert amp.status().mode == "gnd"
                amp.apply(FAST)
                amp.enable()
                amp.step(20)
                assert amp.wait(5.0)
                assert amp.steps_played() == (20, False)
            finally:
                amp.close()
        finally:
            master.disconnect()


@pytest.mark.parametrize("shared", [False, True])
def test_a_bus_gone_is_reported_lost_and_released_without_raising(shared: bool) -> None:
    """The adapter unplugged (python-can: ``CanOperationError``, ENETDOWN, from the receiver):
    the link is lost, and letting it go does not raise that error again (canopen's disconnect
    re-raises it: the daemon's release, then its reconnect, would stop there)."""
    with sim_node() as (_, _, bus):
        if shared:  # the daemon's path: the plate's axes on one network
            axes = open_canopen_axes(bus, {"x": 1}, NODE_ID, heartbeat_s=HEARTBEAT_S, timeout_s=0.5)
            amp = axes["x"]
        else:
            amp = connect(bus)
        assert isinstance(amp, CanopenAmplifier)
        network = amp.network
        assert network.bus is not None
        receive = network.bus._recv_internal
        failed = threading.Event()

        def gone(timeout: float | None) -> tuple[can.Message | None, bool]:
            if not failed.is_set():
                failed.set()
                raise can.CanOperationError("Error receiving: Network is down", 100)
            return receive(timeout)

        network.bus._recv_internal = gone  # type: ignore[method-assign]
        deadline = time.monotonic() + 5.0
        while amp.lost is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert amp.lost is not None and "Network is down" in str(amp.lost)
        if shared:
            axes.release()
        else:
            amp.close()
        assert network.bus is None  # let go all the same


def test_nothing_at_the_node_id_is_not_answering() -> None:
    bus = {"interface": "virtual", "channel": f"test-canopen-link-{uuid.uuid4().hex}"}
    started = time.monotonic()
    with pytest.raises(AmplifierLinkLost, match=f"CANopen node {NODE_ID}: not answering"):
        connect(bus)
    assert time.monotonic() - started < 2.0  # the SDO timeout (and canopen's one retry), not more


# -- the PDO mapping, read from the node ----------------------------------------------------


def remap(record: str, sub: int, entry: int) -> ObjectDictionary:
    """The EDS with mapping ``record``'s entry ``sub`` replaced by ``entry``."""
    od = object_dictionary(NODE_ID)
    mapping = od[record]
    assert isinstance(mapping, ODRecord)
    variable = mapping[sub]
    variable.default = entry
    return od


@pytest.mark.parametrize(
    ("od", "message"),
    [
        (
            remap("TPDO1 mapping parameter", 1, 0x20150010),  # Status word first ...
            "TPDO1 (0x1A00) maps [Status word, Status word, Command acknowledge, Error register], "
            "its EDS [Step counter, Status word, Command acknowledge, Error register]",
        ),
        (
            remap("RPDO1 mapping parameter", 2, 0x20180010),  # a 16-bit sequence
            "RPDO1 (0x1600) maps [Step command, Command sequence (16 bit)], "
            "its EDS [Step command, Command sequence]",
        ),
    ],
    ids=["tpdo", "rpdo"],
)
def test_a_node_mapping_a_pdo_otherwise_is_refused(od: ObjectDictionary, message: str) -> None:
    with sim_node(od) as (_, node, bus):
        with pytest.raises(AmplifierError) as refused:
            connect(bus)
        assert not isinstance(refused.value, AmplifierLinkLost)
        assert isinstance(refused.value, FeederError)
        text = str(refused.value)
        assert "\n" not in text
        assert text.startswith(f"CANopen node {NODE_ID}: {message}: ")
        assert node.nmt_state == 127  # refused before it was started (still PRE-OPERATIONAL)
        heartbeat_ms = int.from_bytes(node.local.get_data(0x1017, 0), "little")
        assert heartbeat_ms == 100  # and before any write (the EDS default)


def test_the_mapping_is_read_from_the_node() -> None:
    def reads_mapping(message: can.Message) -> bool:
        index = int.from_bytes(message.data[1:3], "little")
        return is_sdo_request(message) and index in (0x1600, 0x1A00)

    with sim_node() as (_, _, bus):
        opened: list[CanopenAmplifier] = []
        requests = frames(bus, lambda: opened.append(connect(bus)), reads_mapping)
        opened[0].close()
    assert requests == 1 + 2 + 1 + 4  # RPDO1: count and 2 entries, TPDO1: count and 4


# -- the step count: from the TPDO ------------------------------------------------------------


def test_steps_played_comes_from_the_tpdo_and_is_the_drive_count() -> None:
    with sim_node() as (firmware, _, bus):
        amp = connect(bus)
        try:
            axis = firmware.axis(1)
            amp.apply(FAST)
            amp.enable()
            played: list[tuple[int, bool]] = []

            def burst() -> None:  # the executor's cycle: count, step, confirm the end, count
                played.append(amp.steps_played())
                amp.step(40)
                assert amp.wait(3.0)
                played.append(amp.steps_played())

            assert frames(bus, burst, is_sdo_request) == 0
            assert played == [(0, False), (40, False)]
            assert axis.status().step_counter == 40

            amp.step(100_000)  # 100 s at 1 kHz: cut short
            time.sleep(0.1)

            def cut() -> None:  # the executor's stop: stop, then count
                amp.stop()
                played.append(amp.steps_played())

            assert frames(bus, cut, is_sdo_request) <= 1  # the counter alone, if the TPDO was early
            time.sleep(0.1)
            assert played[-1] == (axis.status().step_counter, False)
            assert 40 < played[-1][0] < 100_040
        finally:
            amp.close()


def test_steps_played_during_a_continuous_run_reads_the_counter() -> None:
    with sim_node() as (firmware, _, bus):
        amp = connect(bus)
        try:
            amp.apply(FAST)
            amp.enable()
            amp.run_continuous(forward=True)
            counts: list[int] = []
            requests = frames(bus, lambda: counts.append(amp.steps_played()[0]), is_sdo_request)
            assert requests == 1  # one object, not a whole status
            assert 0 <= counts[0] <= firmware.axis(1).status().step_counter
            amp.stop()
        finally:
            amp.close()
