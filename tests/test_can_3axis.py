"""One CANopen node with three axes (``feeder_amplifier_3axis.eds``): the EDS, firmware_sim's
node driven by a plain ``canopen`` master, and the host driver, over a ``virtual`` bus.

The node tests tick the firmware by hand (virtual clock), so step counts are exact; the
driver tests tick it in real time in a thread, as tests/test_can_driver.py does.
"""

from __future__ import annotations

import struct
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import can
import canopen
import pytest
from canopen.objectdictionary import ODVariable
from canopen.sdo.exceptions import SdoAbortedError
from test_can_driver import FAST, HEARTBEAT_S
from test_can_node import STATUS_MOVING, STATUS_REFUSED, wait_emcy
from test_eds import variable

from feeder.daemon.config_file import load_config
from feeder.daemon.links import simulator_args
from feeder.drivers.amplifier import AmplifierError, AmplifierLinkLost
from feeder.drivers.axes import open_canopen_axes
from feeder.drivers.canopen import CanopenAmplifier, open_node_axes
from feeder.errors import InputError
from feeder.protocol.eds import (
    EDS_3AXIS_FILE,
    EDS_FILE,
    MODES,
    axis_count,
    axis_object,
    eds_text,
    entry,
    object_dictionary,
)
from firmware_sim.canopen_node import CanopenNode
from firmware_sim.clock import RealTimeClock, VirtualClock
from firmware_sim.faults import Fault
from firmware_sim.firmware import Firmware, FirmwareConfig
from firmware_sim.options import build_parser, check_options

pytestmark = pytest.mark.timeout(60)
NODE_ID = 7
AXES = (1, 2, 3)


def eds_path() -> str:
    """The packaged three-axis EDS as a file a plain master opens."""
    return str(resources.files("feeder.protocol").joinpath(EDS_3AXIS_FILE))


# -- the EDS ---------------------------------------------------------------------


def test_the_eds_alone_says_how_many_axes_a_node_has() -> None:
    one, three = object_dictionary(NODE_ID), object_dictionary(NODE_ID, EDS_3AXIS_FILE)
    assert (axis_count(one), axis_count(three)) == (1, 3)
    assert axis_object(one, 1, "Mode") == "Mode"
    assert axis_object(three, 2, "Mode") == "Axis 2 Mode"
    # CiA 301 multiple device module: 0x1000 additional information FFFFh; one Device type
    # per logical device (axis) at 0x67FF + 0x800·k, and no fourth one
    assert entry(three, "Device type").default == 0xFFFF0000
    assert [three[0x67FF + 0x800 * k].name for k in range(3)] == [f"Axis {n} device type" for n in AXES]
    assert 0x67FF + 0x800 * 3 not in three
    assert three.device_information.nr_of_RXPDO == three.device_information.nr_of_TXPDO == 3


def test_each_axis_has_the_one_axis_objects_0x800_apart() -> None:
    one, three = object_dictionary(NODE_ID), object_dictionary(NODE_ID, EDS_3AXIS_FILE)
    manufacturer = [v for v in one.values() if isinstance(v, ODVariable) and 0x2000 <= v.index < 0x6000]
    assert len(manufacturer) == 16
    for axis in AXES:
        for original in manufacturer:
            moved = three[original.index + 0x800 * (axis - 1)]
            assert isinstance(moved, ODVariable)
            assert moved.name == f"Axis {axis} {original.name}"
            attributes = ("data_type", "access_type", "min", "max", "default", "unit", "pdo_mappable")
            assert [getattr(moved, a) for a in attributes] == [getattr(original, a) for a in attributes]
            assert moved.value_descriptions == original.value_descriptions
            assert moved.bit_definitions == original.bit_definitions
    assert 0x2000 + 0x800 * 3 not in three  # no axis 4


def test_axis_n_has_rpdo_n_and_tpdo_n_mapping_its_own_objects() -> None:
    od = object_dictionary(NODE_ID, EDS_3AXIS_FILE)
    for axis in AXES:
        rpdo, tpdo = variable(od, 0x1400 + axis - 1, 1), variable(od, 0x1800 + axis - 1, 1)
        assert (rpdo.default, tpdo.default) == (0x100 * axis + 0x100 + NODE_ID, 0x100 * axis + 0x80 + NODE_ID)
        mapped_r = [od[(variable(od, 0x1600 + axis - 1, s).default or 0) >> 16].name for s in (1, 2)]
        mapped_t = [od[(variable(od, 0x1A00 + axis - 1, s).default or 0) >> 16].name for s in (1, 2, 3, 4)]
        assert mapped_r == [f"Axis {axis} Step command", f"Axis {axis} Command sequence"]
        assert mapped_t == [
            f"Axis {axis} Step counter",
            f"Axis {axis} Status word",
            f"Axis {axis} Command acknowledge",
            "Error register",  # the node's
        ]


def test_an_unknown_or_foreign_eds_is_one_line_naming_the_field() -> None:
    for eds in ("nope.eds", "pyproject.toml"):
        with pytest.raises(InputError) as error:
            object_dictionary(1, eds, "amplifier.can.eds")
        assert error.value.field == "amplifier.can.eds"
        assert "\n" not in str(error.value)


# -- firmware_sim's node, a plain master ------------------------------------------------


@dataclass
class NodeRig:
    firmware: Firmware
    clock: VirtualClock
    node: CanopenNode
    master: canopen.RemoteNode
    network: canopen.Network

    def run(self, seconds: float) -> None:
        self.firmware.run(self.clock, max_ticks=round(seconds * self.firmware.config.tick_hz))

    def counters(self) -> list[int]:
        return [self.firmware.axis(a).status().step_counter for a in AXES]

    def tpdo_until(self, axis: int, sequence: int) -> canopen.pdo.PdoMap:
        tpdo = self.master.tpdo[axis]
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            if tpdo.is_received and tpdo[f"Axis {axis} Command acknowledge"].raw == sequence:
                return tpdo
            tpdo.wait_for_reception(0.2)
        pytest.fail(f"no TPDO{axis} acknowledging {sequence}")

    def command(self, axis: int, count: int, sequence: int) -> canopen.pdo.PdoMap:
        rpdo = self.master.rpdo[axis]
        rpdo[f"Axis {axis} Step command"].raw = count
        rpdo[f"Axis {axis} Command sequence"].raw = sequence
        rpdo.transmit()
        return self.tpdo_until(axis, sequence)


@pytest.fixture
def node_rig() -> Iterator[NodeRig]:
    channel = f"test-can-3axis-{uuid.uuid4().hex}"
    firmware = Firmware(FirmwareConfig(watchdog_s=5.0))  # in-process: a loaded CI stalls its tick
    od = object_dictionary(NODE_ID, EDS_3AXIS_FILE)
    node = CanopenNode(firmware, AXES, NODE_ID, can.Bus(interface="virtual", channel=channel), od=od)
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.1
    network.connect(interface="virtual", channel=channel)
    master = network.add_node(NODE_ID, eds_path())  # a plain master: the EDS file only
    master.sdo.RESPONSE_TIMEOUT = 1.0
    node.start()
    master.tpdo.read(from_od=True)
    master.rpdo.read(from_od=True)
    yield NodeRig(firmware, VirtualClock(), node, master, network)
    network.disconnect()
    node.close()


def sdo_snapshot(rig: NodeRig) -> list[object]:
    sdo = rig.master.sdo
    return [
        (rig.firmware.axis(a).status(), sdo[f"Axis {a} Frequency"].raw, sdo[f"Axis {a} Amplitude"].raw)
        for a in AXES
    ]


def test_a_plain_master_reads_identity_and_each_axis_own_objects(node_rig: NodeRig) -> None:
    sdo, od = node_rig.master.sdo, node_rig.master.object_dictionary
    assert sdo["Identity object"]["Product code"].raw == od.device_information.product_number == 3
    assert sdo["Device type"].raw == 0xFFFF0000
    assert [sdo[f"Axis {a} device type"].raw for a in AXES] == [0, 0, 0]
    for axis in AXES:
        sdo[f"Axis {axis} Frequency"].raw = 100_000 * axis
        sdo[f"Axis {axis} Amplitude"].raw = 10_000 * axis
    for axis in AXES:
        status = node_rig.firmware.axis(axis).status()
        assert (status.frequency_hz, status.amplitude_v) == (100.0 * axis, 10.0 * axis)
        assert sdo[f"Axis {axis} Frequency"].raw == 100_000 * axis
    node_rig.firmware.axis(3).set_mode("stp")  # the console's change shows on axis 3 only
    assert [sdo[f"Axis {a} Mode"].raw for a in AXES] == [0, 0, MODES.index("stp")]


def test_stepping_axis_2_moves_only_axis_2(node_rig: NodeRig) -> None:
    sdo = node_rig.master.sdo
    for axis in AXES:
        sdo[f"Axis {axis} Frequency"].raw = 1_000_000
        sdo[f"Axis {axis} Amplitude"].raw = 30_000
        sdo[f"Axis {axis} Mode"].raw = MODES.index("stp")
    node_rig.master.nmt.state = "OPERATIONAL"
    tpdo = node_rig.command(2, -120, 5)
    assert int(tpdo["Axis 2 Status word"].raw) & STATUS_MOVING
    node_rig.run(0.3)
    assert node_rig.counters() == [0, -120, 0]
    assert [sdo[f"Axis {a} Step counter"].raw for a in AXES] == [0, -120, 0]
    sdo["Axis 3 Step command"].raw = 7  # by SDO too
    node_rig.run(0.1)
    assert node_rig.counters() == [0, -120, 7]


def test_stop_and_ground_act_on_one_axis(node_rig: NodeRig) -> None:
    sdo = node_rig.master.sdo
    node_rig.master.nmt.state = "OPERATIONAL"  # motion starts in OPERATIONAL only
    for axis in (1, 3):
        sdo[f"Axis {axis} Mode"].raw = MODES.index("stp")
        sdo[f"Axis {axis} Continuous"].raw = 1
    node_rig.run(0.05)
    node_rig.command(1, 0, 1)  # RPDO1 0: axis 1 stops
    node_rig.run(0.05)
    before = node_rig.counters()
    node_rig.run(0.05)
    after = node_rig.counters()
    assert after[0] == before[0] and after[2] > before[2]  # axis 3 runs on
    sdo["Axis 3 Mode"].raw = MODES.index("gnd")
    node_rig.run(0.05)
    statuses = [node_rig.firmware.axis(a).status() for a in AXES]
    assert [s.mode for s in statuses] == ["stp", "gnd", "gnd"]
    assert not any(s.moving for s in statuses)
    tpdo = node_rig.command(3, 10, 2)  # grounded: refused, on axis 3 only
    assert int(tpdo["Axis 3 Status word"].raw) & STATUS_REFUSED
    tpdo = node_rig.command(1, 10, 3)
    assert not int(tpdo["Axis 1 Status word"].raw) & STATUS_REFUSED


@pytest.mark.parametrize(
    ("call", "code"),
    [
        (lambda sdo: sdo.upload(0x2800, 1), 0x06090011),  # Axis 2 Frequency is a plain variable
        (lambda sdo: sdo.upload(0x2021, 0), 0x06020000),  # between objects
        (lambda sdo: sdo.upload(0x3800, 0), 0x06020000),  # axis 4's Frequency: no axis 4
        (lambda sdo: sdo.upload(0x7FFF, 0), 0x06020000),  # logical device 4's device type
        (lambda sdo: sdo.upload(0x1803, 1), 0x06020000),  # TPDO4
        (lambda sdo: sdo.download(0x3001, 0, (300_000).to_bytes(4, "little")), 0x06090031),
        (lambda sdo: sdo.download(0x2812, 0, (5).to_bytes(4, "little")), 0x06010002),  # counter
        (lambda sdo: sdo.upload(0x3011, 0), 0x06010001),  # Axis 3 Continuous: write-only
        (lambda sdo: sdo.download(0x1801, 2, b"\xf8"), 0x06090030),  # TPDO2 type 248
    ],
)
def test_bad_requests_abort_as_cia_301_says_and_change_nothing(
    node_rig: NodeRig, call: object, code: int
) -> None:
    before = sdo_snapshot(node_rig)
    with pytest.raises(SdoAbortedError) as info:
        call(node_rig.master.sdo)  # type: ignore[operator]
    assert info.value.code == code
    assert sdo_snapshot(node_rig) == before


def test_emcy_names_the_axis_and_the_error_register_is_the_nodes(node_rig: NodeRig) -> None:
    sdo = node_rig.master.sdo
    node_rig.master.emcy.reset()
    node_rig.firmware.axis(3).inject_fault(Fault.OVERTEMP)
    emcy = wait_emcy(node_rig.master, 0x4200)
    assert struct.unpack_from("<IB", emcy.data) == (Fault.OVERTEMP, 3)
    assert [sdo[f"Axis {a} Fault word"].raw for a in AXES] == [0, 0, Fault.OVERTEMP]
    assert sdo["Error register"].raw == 0x09
    node_rig.master.nmt.state = "OPERATIONAL"
    tpdo = node_rig.command(1, 0, 1)  # axis 1's TPDO carries the node's register
    assert tpdo["Error register"].raw == 0x09
    sdo["Axis 3 Fault reset"].raw = 1
    assert struct.unpack_from("<IB", wait_emcy(node_rig.master, 0x0000).data) == (0, 3)
    assert sdo["Error register"].raw == 0


def test_leaving_operational_stops_every_axis(node_rig: NodeRig) -> None:
    sdo = node_rig.master.sdo
    node_rig.master.nmt.state = "OPERATIONAL"
    for axis in AXES:
        sdo[f"Axis {axis} Mode"].raw = MODES.index("stp")
        sdo[f"Axis {axis} Continuous"].raw = -1
    node_rig.run(0.05)
    assert all(node_rig.firmware.axis(a).status().moving for a in AXES)
    node_rig.master.nmt.state = "STOPPED"
    assert node_rig.master.nmt.wait_for_heartbeat(2.0) == "STOPPED"
    node_rig.run(0.05)
    assert not any(node_rig.firmware.axis(a).status().moving for a in AXES)


def test_a_node_serves_exactly_the_axes_its_eds_lists() -> None:
    od = object_dictionary(NODE_ID, EDS_3AXIS_FILE)
    with pytest.raises(InputError, match="3 axes, given 1"):
        CanopenNode(Firmware(), 1, NODE_ID, can.Bus(interface="virtual", channel="unused"), od=od)


# -- the host driver --------------------------------------------------------------


@dataclass
class DriverRig:
    firmware: Firmware
    nodes: list[CanopenNode]
    channel: str


def start_nodes(axes: int, eds: str, node_id: int = NODE_ID) -> Iterator[DriverRig]:
    """``axes`` real-time firmware axes as nodes of ``eds`` from ``node_id`` on a virtual bus."""
    channel = f"test-can-3axis-driver-{uuid.uuid4().hex}"
    firmware = Firmware(FirmwareConfig(axes=axes, watchdog_s=5.0))  # in-process: CI stalls its tick
    stop = threading.Event()
    ticker = threading.Thread(target=firmware.run, args=(RealTimeClock(), stop), daemon=True)
    ticker.start()
    per_node = axis_count(object_dictionary(node_id, eds))
    nodes = [
        CanopenNode(
            firmware,
            range(first, first + per_node),
            node_id + (first - 1) // per_node,
            can.Bus(interface="virtual", channel=channel),
            od=object_dictionary(node_id + (first - 1) // per_node, eds),
        ).start()
        for first in range(1, axes + 1, per_node)
    ]
    yield DriverRig(firmware, nodes, channel)
    for node in nodes:
        if node.network.bus is not None:
            node.close()
    stop.set()
    ticker.join(timeout=2.0)


@pytest.fixture
def driver_rig() -> Iterator[DriverRig]:
    yield from start_nodes(3, EDS_3AXIS_FILE)


def open_amps(rig: DriverRig, **options: Any) -> dict[int, CanopenAmplifier]:
    return open_node_axes(
        {"interface": "virtual", "channel": rig.channel},
        NODE_ID,
        eds=object_dictionary(NODE_ID, EDS_3AXIS_FILE),
        heartbeat_s=HEARTBEAT_S,
        timeout_s=0.5,
        **options,
    )


def close_all(amps: dict[int, CanopenAmplifier]) -> None:
    for amp in amps.values():
        amp.close()


def test_one_link_per_node_and_a_step_on_axis_2_moves_only_axis_2(driver_rig: DriverRig) -> None:
    amps = open_amps(driver_rig)
    try:
        assert sorted(amps) == [1, 2, 3]
        assert len({id(amp.link) for amp in amps.values()}) == 1
        for amp in amps.values():
            amp.apply(FAST)
            amp.enable()
        amps[2].step(40)
        assert amps[2].wait(5.0)
        counters = [driver_rig.firmware.axis(a).status().step_counter for a in AXES]
        assert counters == [0, 40, 0]
        assert [amp.status().step_counter for amp in amps.values()] == counters
        assert [amp.step_counter for amp in amps.values()] == counters  # from each axis' TPDO
    finally:
        close_all(amps)


def test_stop_and_ground_per_axis_through_the_driver(driver_rig: DriverRig) -> None:
    amps = open_amps(driver_rig)
    axes = [driver_rig.firmware.axis(a) for a in AXES]
    try:
        for number in (1, 3):
            amps[number].apply(FAST)
            amps[number].enable()
            amps[number].run_continuous(forward=True)
        amps[1].stop()
        assert amps[1].wait(2.0)
        assert not axes[0].status().moving and axes[2].status().moving
        amps[3].ground()
        assert [axis.status().mode for axis in axes] == ["stp", "gnd", "gnd"]
        assert amps[3].wait(2.0)
        with pytest.raises(AmplifierError, match="node 7 axis 3: step 5 refused"):
            amps[3].step(5)
        with pytest.raises(AmplifierError, match=r"node 7 axis 2: Axis 2 Amplitude = 250000: value too high"):
            amps[2].apply(FAST.__class__(frequency_hz=1000.0, amplitude_v=250.0))
    finally:
        close_all(amps)


def test_the_host_beats_once_per_node_not_per_axis(driver_rig: DriverRig) -> None:
    listener = can.Bus(interface="virtual", channel=driver_rig.channel)
    amps = open_amps(driver_rig, supervise_host=True)
    try:
        window_s, host_beats = 1.0, 0
        deadline = time.monotonic() + window_s
        while time.monotonic() < deadline:
            frame = listener.recv(0.05)
            host_beats += frame is not None and frame.arbitration_id == 0x700 + 127
        # one beat every HEARTBEAT_S: ~5 in the window (three per-axis tasks would send ~15)
        assert 1 <= host_beats <= 1.5 * window_s / HEARTBEAT_S + 1
        amps[1].close()  # the node still watches us while axes 2 and 3 are open
        assert amps[2].link.host_heartbeat is not None
        assert driver_rig.nodes[0]._consumer_id == 127
    finally:
        close_all(amps)
        listener.shutdown()
    assert driver_rig.nodes[0]._consumer_id == 0  # the last axis closed: consumer off


def test_a_lost_node_faults_all_its_axes(driver_rig: DriverRig) -> None:
    amps = open_amps(driver_rig)
    try:
        for amp in amps.values():
            amp.apply(FAST)
            amp.enable()
        amps[1].run_continuous(forward=True)
        driver_rig.nodes[0].close()  # no more heartbeats
        with pytest.raises(AmplifierLinkLost, match="no heartbeat"):
            amps[1].wait(10.0)
        for amp in amps.values():
            assert "no heartbeat" in (amp.lost or "")
            with pytest.raises(AmplifierLinkLost):
                amp.step(3)
            with pytest.raises(AmplifierLinkLost):
                amp.ground()
    finally:
        close_all(amps)


def test_the_eds_must_be_the_nodes(driver_rig: DriverRig) -> None:
    bus = {"interface": "virtual", "channel": driver_rig.channel}
    with pytest.raises(AmplifierError, match="is product 0x00000003, its EDS describes 0x00000001"):
        CanopenAmplifier(bus, NODE_ID, heartbeat_s=HEARTBEAT_S)  # the one-axis EDS
    with pytest.raises(InputError, match=r"has axes 1\.\.3, not 4"):
        CanopenAmplifier(bus, NODE_ID, object_dictionary(NODE_ID, EDS_3AXIS_FILE), HEARTBEAT_S, axis=4)


def test_a_one_axis_node_refuses_the_three_axis_eds() -> None:
    for rig in start_nodes(1, EDS_FILE):
        bus = {"interface": "virtual", "channel": rig.channel}
        with pytest.raises(AmplifierError, match="is product 0x00000001, its EDS describes 0x00000003"):
            open_node_axes(
                bus, NODE_ID, eds=object_dictionary(NODE_ID, EDS_3AXIS_FILE), heartbeat_s=HEARTBEAT_S
            )


def test_open_canopen_axes_maps_amplifier_axes_to_nodes_by_the_eds() -> None:
    """Six axes as two three-axis nodes: amplifier axis n is axis (n − 1) mod 3 + 1 of node
    7 + (n − 1) div 3."""
    for rig in start_nodes(6, EDS_3AXIS_FILE):
        bus = {"interface": "virtual", "channel": rig.channel}
        axis_map = {"x": 1, "y": 4, "theta": 6}
        with open_canopen_axes(bus, axis_map, NODE_ID, EDS_3AXIS_FILE, heartbeat_s=HEARTBEAT_S) as axes:
            places = {name: (amp.node_id, amp.axis) for name, amp in axes.items()}  # type: ignore[attr-defined]
            assert places == {"x": (7, 1), "y": (8, 1), "theta": (8, 3)}
            assert axes["y"].link is axes["theta"].link is not axes["x"].link  # type: ignore[attr-defined]
            axes["theta"].apply(FAST)
            axes["theta"].enable()
            axes["theta"].step(-9)
            assert axes["theta"].wait(5.0)
            assert [rig.firmware.axis(a).status().step_counter for a in range(1, 7)] == [0, 0, 0, 0, 0, -9]
        with pytest.raises(InputError, match=r"node ids 126\.\.128"):
            open_canopen_axes(bus, {"x": 1, "y": 7}, 126, EDS_3AXIS_FILE)


# -- configuration: firmware_sim's options, the daemon's [amplifier.can] eds -----------


def options(*args: str) -> None:
    check_options(build_parser().parse_args(list(args)))


def test_firmware_sim_can_eds_option_is_checked() -> None:
    options("--can", "slcan-pty", "--can-eds", EDS_3AXIS_FILE)  # 3 axes: one node
    options("--can", "slcan-pty", "--can-eds", EDS_3AXIS_FILE, "--axes", "6", "--can-node-id-base", "126")
    for args, field in [
        (["--can-eds", EDS_3AXIS_FILE, "--axes", "2"], "--can-eds"),
        (["--can-eds", "nope.eds"], "--can-eds"),
        (["--can-eds", EDS_3AXIS_FILE, "--axes", "6", "--can-node-id-base", "127"], "--can-node-id-base"),
        (["--axes", "3", "--can-node-id-base", "126"], "--can-node-id-base"),
    ]:
        with pytest.raises(InputError) as error:
            options("--can", "slcan-pty", *args)
        assert error.value.field == field
        assert "\n" not in str(error.value)


def test_the_daemon_config_names_the_eds(tmp_path: Path) -> None:
    base = tmp_path
    good = base / "good.toml"
    good.write_text(f'[amplifier]\ntransport = "can"\n[amplifier.can]\neds = "{EDS_3AXIS_FILE}"\n')
    config = load_config(good)
    assert config.amplifier.simulated  # an EDS alone names no bus
    args = simulator_args(config)
    assert args[args.index("--can-eds") + 1] == EDS_3AXIS_FILE
    # a path is the configuration's neighbour, wherever the daemon is started from
    lab = base / "lab"
    lab.mkdir()
    (lab / "drive.eds").write_text(eds_text(EDS_3AXIS_FILE))
    (lab / "lab.toml").write_text('[amplifier]\ntransport = "can"\n[amplifier.can]\neds = "drive.eds"\n')
    assert load_config(lab / "lab.toml").amplifier.can["eds"] == str(lab / "drive.eds")
    refusals = [('"nope.eds"', "nope.eds"), ("3", "must be a string")]
    for value, expected in refusals:
        bad = base / "bad.toml"
        bad.write_text(f'[amplifier]\ntransport = "can"\n[amplifier.can]\neds = {value}\n')
        with pytest.raises(InputError) as error:
            load_config(bad)
        assert expected in str(error.value) and "amplifier.can.eds" in str(error.value)
        assert "\n" not in str(error.value)
    assert "--can-eds" not in simulator_args(load_config(None).with_transport("can"))
