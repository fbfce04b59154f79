"""Acceptance: a plain ``canopen`` master, given only the EDS and the pty path of
``python -m firmware_sim --can slcan-pty``, reads the identity, sets frequency and
amplitude, steps the axis and sees the counter advance; bad writes are refused."""

from __future__ import annotations

import time
from collections.abc import Iterator

import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError

from feeder.daemon.launcher import Simulator
from feeder.protocol.eds import object_dictionary

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def master() -> Iterator[tuple[Simulator, canopen.RemoteNode]]:
    sim = Simulator(["--can", "slcan-pty", "--axes", "2", "--can-node-id-base", "10"])
    network = canopen.Network()
    network.connect(interface="slcan", channel=sim.endpoints["slcan_pty"], bitrate=500000, sleep_after_open=0)
    node = network.add_node(11, object_dictionary(11))  # axis 2
    node.sdo.RESPONSE_TIMEOUT = 2.0
    yield sim, node
    network.disconnect()
    sim.stop()


def test_identity_settings_and_steps(master: tuple[Simulator, canopen.RemoteNode]) -> None:
    _, node = master
    assert node.nmt.wait_for_heartbeat(5.0) == "PRE-OPERATIONAL"
    od = node.object_dictionary
    identity = node.sdo["Identity object"]
    assert identity["Vendor-ID"].raw == od.device_information.vendor_number
    assert identity["Product code"].raw == od.device_information.product_number
    assert identity["Revision number"].raw == od.device_information.revision_number
    assert node.sdo["Manufacturer device name"].raw == "feeder stick-slip amplifier"

    node.sdo["Frequency"].raw = 1_000_000
    node.sdo["Amplitude"].raw = 120_000
    node.sdo["Mode"].raw = 3  # stp
    assert (node.sdo["Frequency"].raw, node.sdo["Amplitude"].raw, node.sdo["Mode"].raw) == (
        1_000_000,
        120_000,
        3,
    )

    node.tpdo.read()  # PDO set-up read from the node by SDO
    node.rpdo.read()
    node.nmt.state = "OPERATIONAL"
    start = node.sdo["Step counter"].raw
    node.rpdo[1]["Step command"].raw = 250
    node.rpdo[1]["Command sequence"].raw = 1
    node.rpdo[1].transmit()
    tpdo = node.tpdo[1]
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        tpdo.wait_for_reception(0.5)
        if tpdo["Step counter"].raw == start + 250 and not int(tpdo["Status word"].raw) & 1:
            break
    assert tpdo["Step counter"].raw == start + 250
    assert tpdo["Command acknowledge"].raw == 1
    assert node.sdo["Step counter"].raw == start + 250


@pytest.mark.parametrize(
    ("index", "value", "code"),
    [
        ("Amplitude", 300_000, 0x06090031),
        ("Frequency", 0, 0x06090032),
        ("Step counter", 1, 0x06010002),
        (0x2999, 1, 0x06020000),
    ],
)
def test_bad_writes_are_refused_over_slcan(
    master: tuple[Simulator, canopen.RemoteNode], index: str | int, value: int, code: int
) -> None:
    _, node = master
    before = (node.sdo["Frequency"].raw, node.sdo["Amplitude"].raw, node.sdo["Step counter"].raw)
    with pytest.raises(SdoAbortedError) as info:
        if isinstance(index, int):
            node.sdo.download(index, 0, value.to_bytes(4, "little"))
        else:
            node.sdo[index].raw = value
    assert info.value.code == code
    assert (node.sdo["Frequency"].raw, node.sdo["Amplitude"].raw, node.sdo["Step counter"].raw) == before


def test_garbage_lines_and_unknown_frames_do_no_harm(master: tuple[Simulator, canopen.RemoteNode]) -> None:
    sim, node = master
    network = node.network
    before = (
        node.sdo["Frequency"].raw,
        node.sdo["Amplitude"].raw,
        node.sdo["Mode"].raw,
        node.sdo["Step counter"].raw,
    )
    port = network.bus.serialPortOrig  # type: ignore[union-attr]
    port.write(b"\xff\xfe\x00\x07zz\rt12\rT1\rd1230\rt8000\r" + b"t" * 5000 + b"\r\n")
    for can_id in (0x123, 0x7FF, 0x580 + 11, 0x700 + 3, 0x080, 0x601, 0x20B):
        network.send_message(can_id, b"\x01\x02")  # unknown ids, short SDO/RPDO, SYNC
    network.send_message(0x000, b"\x81\x05")  # reset for another node
    time.sleep(0.3)
    assert sim.alive()
    assert (
        node.sdo["Frequency"].raw,
        node.sdo["Amplitude"].raw,
        node.sdo["Mode"].raw,
        node.sdo["Step counter"].raw,
    ) == before
