"""Hardware in the loop, one CANopen node with three axes: ``python -m firmware_sim --can
slcan-pty --can-eds feeder_amplifier_3axis.eds`` behind its emulated SLCAN adapter (a pty,
as a USB adapter; never vcan or udp_multicast), driven by a plain ``canopen`` master given
only the EDS, by :func:`~feeder.drivers.axes.open_canopen_axes` against the planar plant's
true poses, and by the daemon's own links from its configuration."""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError
from test_axes import (
    DRIVE,
    PART,
    each_axis_moves_only_its_own_plate_axis,
    open_axes,
    settled,
    start,
)
from test_can_3axis import eds_path

from feeder.cli.demo_plane import config_for
from feeder.daemon.config import DaemonConfig
from feeder.daemon.launcher import Simulator
from feeder.daemon.links import open_links
from feeder.drivers.axes import Axes
from feeder.drivers.camera import StreamCamera
from feeder.drivers.canopen import CanopenAmplifier
from feeder.drivers.sensor import PositionSensor
from feeder.parts import Part
from feeder.protocol.eds import EDS_3AXIS_FILE, MODES

pytestmark = pytest.mark.timeout(180)
BASE = 10


@pytest.fixture(scope="module")
def master() -> Iterator[tuple[Simulator, canopen.RemoteNode]]:
    sim = Simulator(["--can", "slcan-pty", "--can-eds", EDS_3AXIS_FILE, "--can-node-id-base", str(BASE)])
    network = canopen.Network()
    network.connect(interface="slcan", channel=sim.endpoints["slcan_pty"], bitrate=500000, sleep_after_open=0)
    node = network.add_node(BASE, eds_path())  # a plain master: the EDS file, nothing of feeder's
    node.sdo.RESPONSE_TIMEOUT = 2.0
    yield sim, node
    network.disconnect()
    sim.stop()


def test_one_node_beats_for_three_axes(master: tuple[Simulator, canopen.RemoteNode]) -> None:
    _, node = master
    seen: set[int] = set()

    class Ids(can.Listener):
        def on_message_received(self, msg: can.Message) -> None:
            seen.add(msg.arbitration_id)

    listener = Ids()
    assert node.network.notifier is not None
    node.network.notifier.add_listener(listener)
    time.sleep(0.5)  # five heartbeat periods
    node.network.notifier.remove_listener(listener)
    assert {i for i in seen if 0x701 <= i <= 0x77F} == {0x700 + BASE}


def test_a_plain_master_reads_identity_and_steps_axis_2_only(
    master: tuple[Simulator, canopen.RemoteNode],
) -> None:
    _, node = master
    assert node.nmt.wait_for_heartbeat(5.0) in ("PRE-OPERATIONAL", "OPERATIONAL")
    od = node.object_dictionary
    identity = node.sdo["Identity object"]
    assert identity["Vendor-ID"].raw == od.device_information.vendor_number
    assert identity["Product code"].raw == od.device_information.product_number == 3
    assert node.sdo["Device type"].raw == 0xFFFF0000
    for axis in (1, 2, 3):
        node.sdo[f"Axis {axis} Frequency"].raw = 500_000 * axis
        node.sdo[f"Axis {axis} Amplitude"].raw = 40_000
        node.sdo[f"Axis {axis} Mode"].raw = MODES.index("stp")
    assert [node.sdo[f"Axis {a} Frequency"].raw for a in (1, 2, 3)] == [500_000, 1_000_000, 1_500_000]

    node.tpdo.read()  # PDO set-up read from the node by SDO
    node.rpdo.read()
    node.nmt.state = "OPERATIONAL"
    before = [node.sdo[f"Axis {a} Step counter"].raw for a in (1, 2, 3)]
    node.rpdo[2]["Axis 2 Step command"].raw = 250
    node.rpdo[2]["Axis 2 Command sequence"].raw = 1
    node.rpdo[2].transmit()
    tpdo = node.tpdo[2]
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        tpdo.wait_for_reception(0.5)
        if tpdo["Axis 2 Step counter"].raw == before[1] + 250 and not int(tpdo["Axis 2 Status word"].raw) & 1:
            break
    assert tpdo["Axis 2 Command acknowledge"].raw == 1
    after = [node.sdo[f"Axis {a} Step counter"].raw for a in (1, 2, 3)]
    assert after == [before[0], before[1] + 250, before[2]]


@pytest.mark.parametrize(
    ("index", "subindex", "code"),
    [(0x2800, 1, 0x06090011), (0x3800, 0, 0x06020000), (0x2099, 0, 0x06020000)],
)
def test_wrong_objects_and_sub_indices_abort_over_slcan(
    master: tuple[Simulator, canopen.RemoteNode], index: int, subindex: int, code: int
) -> None:
    _, node = master
    with pytest.raises(SdoAbortedError) as info:
        node.sdo.upload(index, subindex)
    assert info.value.code == code


def stops_every_axis(axes: Axes, camera: PositionSensor) -> None:
    """A long burst on x, then :meth:`Axes.stop`: the part stops far short of the burst.

    (test_axes' ``stop_on_all_axes`` bounds the run-on by 1 mm, ~300 steps: on the virtual
    clock the plant runs as fast as the CPU allows, so the run-on measures the machine's
    load as much as the link; measured 14–53 µm with one node per axis, 16–122 µm with one
    node of three axes on a loaded 2-core machine.)"""
    before = settled(camera)
    axes["x"].step(100_000)  # 0.3 m worth of steps
    camera.read(30.0)
    axes.stop()
    stopped = settled(camera)
    assert not any(amplifier.status().moving for amplifier in axes.values())
    assert 0 < stopped[0] - before[0] < 0.5e-3
    time.sleep(0.2)
    assert settled(camera) == pytest.approx(stopped, abs=1e-9)


def test_open_canopen_axes_drives_the_three_axes_of_one_node_in_the_plane() -> None:
    sim = start("can", "--can-eds", EDS_3AXIS_FILE)
    try:
        axes = open_axes(sim, "can", EDS_3AXIS_FILE)
        with StreamCamera(sim.endpoints["sensor_tcp"]) as camera, axes:
            assert {(amp.node_id, amp.axis) for amp in axes.values()} == {(1, 1), (1, 2), (1, 3)}  # type: ignore[attr-defined]
            for amplifier in axes.values():
                amplifier.apply(DRIVE)
                amplifier.enable()
            each_axis_moves_only_its_own_plate_axis(axes, camera)
            stops_every_axis(axes, camera)
        again = open_axes(sim, "can", EDS_3AXIS_FILE)  # closing grounded every axis
        with again:
            assert [amplifier.status().mode for amplifier in again.values()] == ["gnd"] * 3
    finally:
        sim.stop()
    assert PART  # the part the plane starts from (test_axes.start)


def test_the_daemon_links_open_one_node_for_x_y_and_theta() -> None:
    """[amplifier.can] eds: the daemon starts firmware_sim with that EDS and opens the
    plate's three axes on one node."""
    base = Path(tempfile.mkdtemp(prefix="f3ax"))
    config = config_for(Part.parse("300x300x50"), "can", base)
    amp = dataclasses.replace(config.amplifier, can={**config.amplifier.can, "eds": EDS_3AXIS_FILE})
    config = dataclasses.replace(config, amplifier=amp)
    links = open_links(config)
    try:
        axes = links.open_amplifier()
        assert isinstance(axes, Axes)
        with axes:
            placed = {name: (a.node_id, a.axis) for name, a in axes.items()}  # type: ignore[attr-defined]
            assert placed == {"x": (1, 1), "y": (1, 2), "theta": (1, 3)}
            assert len({id(a.link) for a in axes.values()}) == 1  # type: ignore[attr-defined]
            before = {name: a.status().step_counter for name, a in axes.items()}
            axes["y"].apply(DRIVE)
            axes["y"].enable()
            axes["y"].step(3)
            assert axes["y"].wait(60.0)
            after = {name: a.status().step_counter for name, a in axes.items()}
            assert after == {**before, "y": before["y"] + 3}
            # by default the node consumes the daemon's heartbeat: a daemon that dies mid-move
            # (here: stops beating) gets the moving axis grounded, with a latched fault
            axes["y"].step(100_000)
            axes["y"]._host_heartbeat.stop()  # type: ignore[attr-defined]
            deadline = time.monotonic() + 5.0
            while axes["y"].status().mode != "gnd" and time.monotonic() < deadline:
                time.sleep(0.02)
            assert (axes["y"].status().mode, axes["y"].status().faults) == ("gnd", ("host_watchdog",))
    finally:
        links.close()
        shutil.rmtree(base, ignore_errors=True)


def test_a_one_axis_plate_drives_amplifier_axis_of_the_three_axis_node() -> None:
    """Not in the plane: ``[amplifier] axis`` picks the axis of node ``node_id``."""
    base = Path(tempfile.mkdtemp(prefix="f3ax1"))
    config = DaemonConfig(state_dir=base / "state", socket_path=base / "run" / "s.sock").with_transport("can")
    amp = dataclasses.replace(config.amplifier, can={"eds": EDS_3AXIS_FILE}, axis=2)
    links = open_links(dataclasses.replace(config, amplifier=amp))
    try:
        driver = links.open_amplifier()
        assert isinstance(driver, CanopenAmplifier)
        try:
            assert (driver.node_id, driver.axis, driver.who) == (1, 2, "CANopen node 1 axis 2")
            driver.enable()
            assert driver.status().mode == "stp"
        finally:
            driver.ground()
            driver.close()
    finally:
        links.close()
        shutil.rmtree(base, ignore_errors=True)
