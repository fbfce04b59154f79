"""The node's SDO server against CiA 301, frame by frame, on firmware_sim's CAN wire.

On the wire a request is handled in the sending thread, so each request's
answer is there when ``send`` returns: no sleeps, no timeouts.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Iterator
from dataclasses import dataclass

import can
import pytest

from feeder.protocol.eds import object_dictionary
from firmware_sim.can_wire import CanWire, WireBus
from firmware_sim.canopen_node import CanopenNode
from firmware_sim.firmware import Firmware

pytestmark = pytest.mark.timeout(30)
NODE_ID = 6
ABORT_COMMAND = 0x05040001
ABORT_NO_OBJECT = 0x06020000
ABORT_NO_SUBINDEX = 0x06090011
ABORT_READ_ONLY = 0x06010002
ABORT_TOO_HIGH = 0x06090031
OD = object_dictionary(NODE_ID)
FREQUENCY = OD["Frequency"].index
DEVICE_NAME = OD["Manufacturer device name"].index  # a string: segmented upload
STEP_COUNTER = OD["Step counter"].index  # read-only
IDENTITY = OD["Identity object"].index


@dataclass
class Rig:
    firmware: Firmware
    node: CanopenNode
    host: WireBus
    answers: list[tuple[bytes, int]]  # (data, thread id) of every frame from 0x580 + id

    def request(self, data: bytes) -> bytes | None:
        """Send one SDO request; the answer it got (None: no answer)."""
        before = len(self.answers)
        self.host.send(
            can.Message(arbitration_id=0x600 + NODE_ID, is_extended_id=False, data=data.ljust(8, b"\0"))
        )
        assert len(self.answers) - before <= 1
        return self.answers[-1][0] if len(self.answers) > before else None


@pytest.fixture
def rig() -> Iterator[Rig]:
    firmware = Firmware()
    wire = CanWire()
    answers: list[tuple[bytes, int]] = []

    def collect(message: can.Message) -> None:
        if message.arbitration_id == 0x580 + NODE_ID:
            answers.append((bytes(message.data), threading.get_ident()))

    host = wire.bus(collect)
    node = CanopenNode(firmware, 1, NODE_ID, wire.bus()).start()
    yield Rig(firmware, node, host, answers)
    node.close()
    host.shutdown()


def initiate(ccs: int, index: int, subindex: int, payload: bytes = b"") -> bytes:
    return struct.pack("<BHB", ccs, index, subindex) + payload


def abort_code(answer: bytes | None) -> int | None:
    assert answer is not None, "no answer"
    return struct.unpack_from("<L", answer, 4)[0] if answer[0] == 0x80 else None


def expedited_upload(rig: Rig, index: int, subindex: int = 0) -> int:
    answer = rig.request(initiate(0x40, index, subindex))
    assert answer is not None and answer[0] & 0xE3 == 0x43, answer
    return int.from_bytes(answer[4:8], "little")


def test_a_request_is_answered_in_the_thread_that_delivered_it(rig: Rig) -> None:
    assert expedited_upload(rig, FREQUENCY) == 100_000
    assert rig.answers[-1][1] == threading.get_ident()


def test_unknown_object_aborts_0x06020000(rig: Rig) -> None:
    assert abort_code(rig.request(initiate(0x40, 0x2100, 0))) == ABORT_NO_OBJECT
    assert abort_code(rig.request(initiate(0x23, 0x5FFF, 0, b"\x01\0\0\0"))) == ABORT_NO_OBJECT
    assert abort_code(rig.request(initiate(0x21, 0x5FFF, 0, b"\x04\0\0\0"))) == ABORT_NO_OBJECT


@pytest.mark.parametrize("subindex", [1, 5, 255])
def test_unknown_sub_index_of_a_variable_aborts_0x06090011(rig: Rig, subindex: int) -> None:
    """Not served as sub-index 0: read and write are refused, nothing changes."""
    assert abort_code(rig.request(initiate(0x40, FREQUENCY, subindex))) == ABORT_NO_SUBINDEX
    write = initiate(0x23, FREQUENCY, subindex, (250_000).to_bytes(4, "little"))
    assert abort_code(rig.request(write)) == ABORT_NO_SUBINDEX
    assert rig.firmware.axis(1).status().frequency_hz == 100.0
    assert expedited_upload(rig, FREQUENCY) == 100_000


def test_unknown_sub_index_of_a_record_aborts_0x06090011(rig: Rig) -> None:
    assert abort_code(rig.request(initiate(0x40, IDENTITY, 9))) == ABORT_NO_SUBINDEX
    assert expedited_upload(rig, IDENTITY, 0) == 4


def test_a_client_abort_ends_a_segmented_upload(rig: Rig) -> None:
    answer = rig.request(initiate(0x40, DEVICE_NAME, 0))
    assert answer is not None and answer[0] == 0x41  # segmented, size given
    size = int.from_bytes(answer[4:8], "little")
    first = rig.request(b"\x60")
    assert first is not None and first[1:8] == b"feeder "
    assert rig.node.local.sdo.transfer == "upload"
    assert rig.request(initiate(0x80, DEVICE_NAME, 0, (0x05040000).to_bytes(4, "little"))) is None
    assert rig.node.local.sdo.transfer is None
    assert abort_code(rig.request(b"\x70")) == ABORT_COMMAND  # the next segment: no transfer
    # a new transfer starts from the beginning
    answer = rig.request(initiate(0x40, DEVICE_NAME, 0))
    assert answer is not None and int.from_bytes(answer[4:8], "little") == size
    text, toggle = b"", 0
    while True:
        segment = rig.request(bytes([0x60 | toggle]))
        assert segment is not None and segment[0] & 0xE0 == 0x00
        text += segment[1 : 8 - (segment[0] >> 1 & 7)]
        toggle ^= 0x10
        if segment[0] & 1:
            break
    assert text == b"feeder stick-slip amplifier" and len(text) == size


def test_a_client_abort_ends_a_segmented_download_and_writes_nothing(rig: Rig) -> None:
    value = (250_000).to_bytes(4, "little")
    answer = rig.request(initiate(0x21, FREQUENCY, 0, (4).to_bytes(4, "little")))
    assert answer is not None and answer[0] == 0x60
    assert rig.request(initiate(0x80, FREQUENCY, 0, (0x05040000).to_bytes(4, "little"))) is None
    assert abort_code(rig.request(bytes([0x07]) + value)) == ABORT_COMMAND
    assert rig.firmware.axis(1).status().frequency_hz == 100.0
    # the same download, not aborted, goes through the node's limits and reaches the firmware
    rig.request(initiate(0x21, FREQUENCY, 0, (4).to_bytes(4, "little")))
    assert rig.request(bytes([0x07]) + value) == bytes([0x20]) + bytes(7)
    assert rig.firmware.axis(1).status().frequency_hz == 250.0
    rig.request(initiate(0x21, FREQUENCY, 0, (4).to_bytes(4, "little")))
    too_high = (OD["Frequency"].max + 1).to_bytes(4, "little")
    assert abort_code(rig.request(bytes([0x07]) + too_high)) == ABORT_TOO_HIGH
    assert rig.firmware.axis(1).status().frequency_hz == 250.0


def test_segments_outside_a_transfer_and_block_download_abort_0x05040001(rig: Rig) -> None:
    assert abort_code(rig.request(b"\x60")) == ABORT_COMMAND  # upload segment
    assert abort_code(rig.request(b"\x01abc")) == ABORT_COMMAND  # download segment
    assert abort_code(rig.request(initiate(0xC0, FREQUENCY, 0))) == ABORT_COMMAND  # block
    # an expedited transfer leaves no segmented one behind
    expedited_upload(rig, FREQUENCY)
    assert abort_code(rig.request(b"\x60")) == ABORT_COMMAND
    # a new initiate ends the transfer in progress
    rig.request(initiate(0x40, DEVICE_NAME, 0))
    expedited_upload(rig, FREQUENCY)
    assert abort_code(rig.request(b"\x60")) == ABORT_COMMAND


def test_a_segmented_download_to_a_read_only_object_is_refused_before_any_data(rig: Rig) -> None:
    answer = rig.request(initiate(0x21, STEP_COUNTER, 0, (4).to_bytes(4, "little")))
    assert abort_code(answer) == ABORT_READ_ONLY
    assert abort_code(rig.request(b"\x07\x01\x00\x00\x00")) == ABORT_COMMAND


def test_a_request_waits_for_the_firmware_lock(rig: Rig) -> None:
    """An SDO write is applied between two ticks, never inside one."""
    answered = threading.Event()

    def write() -> None:
        rig.request(initiate(0x23, FREQUENCY, 0, (300_000).to_bytes(4, "little")))
        answered.set()

    with rig.firmware.lock:  # as the tick holds it
        writer = threading.Thread(target=write)
        writer.start()
        assert not answered.wait(0.1)
        assert rig.firmware.axis(1).status().frequency_hz == 100.0
    writer.join(2.0)
    assert answered.is_set() and rig.firmware.axis(1).status().frequency_hz == 300.0
