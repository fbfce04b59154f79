"""The emulated Lawicel SLCAN adapter: protocol unit tests, fuzzing, and python-can's
``slcan`` interface talking to it over a real pty."""

from __future__ import annotations

import time
import uuid
from collections.abc import Iterator
from typing import cast

import can
import pytest
from can.interfaces.slcan import slcanBus
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.slcan import ERROR, FLAG_DATA_OVERRUN, OK, SlcanAdapter, SlcanPty

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def buses() -> Iterator[tuple[can.BusABC, can.BusABC]]:
    """The adapter's CAN side and a peer on the same virtual channel."""
    channel = f"test-slcan-{uuid.uuid4().hex}"
    side = can.Bus(interface="virtual", channel=channel)
    peer = can.Bus(interface="virtual", channel=channel)
    yield side, peer
    side.shutdown()
    peer.shutdown()


def same_frame(a: can.Message, b: can.Message) -> bool:
    return (a.arbitration_id, a.is_extended_id, a.is_remote_frame, a.dlc, bytes(a.data)) == (
        b.arbitration_id,
        b.is_extended_id,
        b.is_remote_frame,
        b.dlc,
        bytes(b.data),
    )


def test_python_can_startup_sequence_and_info_commands(buses: tuple[can.BusABC, can.BusABC]) -> None:
    adapter = SlcanAdapter(buses[0], serial_number="AB12")
    # exactly what python-can's slcanBus(bitrate=500000) writes on open
    assert [adapter.handle_line(c) for c in (b"C", b"S6", b"", b"O", b"O")] == [OK, OK, b"", OK, ERROR]
    assert (adapter.is_open, adapter.bitrate) == (True, 500_000)
    assert adapter.handle_line(b"S4") == ERROR  # bit rate only while closed
    assert adapter.handle_line(b"V") == b"V1013\r"
    assert adapter.handle_line(b"N") == b"NAB12\r"
    assert adapter.handle_line(b"F") == b"F00\r"
    assert adapter.handle_line(b"C") == OK
    assert adapter.handle_line(b"L") == OK and adapter.listen_only
    assert adapter.handle_line(b"t1230") == ERROR  # listen-only: no transmit


@pytest.mark.parametrize(
    ("line", "frame"),
    [
        (b"t1232DEAD", can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\xde\xad")),
        (b"t7FF0", can.Message(arbitration_id=0x7FF, is_extended_id=False, data=b"")),
        (
            b"T1ABCDEF08" + b"01" * 8,
            can.Message(arbitration_id=0x1ABCDEF0, is_extended_id=True, data=b"\x01" * 8),
        ),
        (b"r0054", can.Message(arbitration_id=0x005, is_extended_id=False, is_remote_frame=True, dlc=4)),
        (b"R000000012", can.Message(arbitration_id=1, is_extended_id=True, is_remote_frame=True, dlc=2)),
    ],
)
def test_transmit_lines_become_frames(
    buses: tuple[can.BusABC, can.BusABC], line: bytes, frame: can.Message
) -> None:
    side, peer = buses
    adapter = SlcanAdapter(side)
    adapter.handle_line(b"O")
    assert adapter.handle_line(line) == (b"Z\r" if frame.is_extended_id else b"z\r")
    received = peer.recv(1.0)
    assert received is not None and same_frame(received, frame)
    # ... and the adapter announces the frame with the very same line
    assert adapter.frame_line(frame) == line + OK


MALFORMED = [
    b"t1232DEA",  # data shorter than DLC
    b"t1232DEADBE",  # longer
    b"t12390000000000000000",  # DLC 9
    b"t8000",  # standard id > 0x7FF
    b"T200000000",  # extended id > 0x1FFFFFFF
    b"t12G0",  # not hex
    b"t12",  # truncated
    b"r1232AA",  # remote frame with data
    b"d1230",  # CAN FD: not supported
    b"X",
    b"Q",
    b"S9",
    b"S",
    b"s12",
    b"Z2",
    b"M123",
    b"Oxx",
    b"VV",
    "t1231é".encode(),  # non-ASCII
    b"t123" + b"0" * 40,  # over 32 bytes
]


@pytest.mark.parametrize("line", MALFORMED)
def test_malformed_lines_get_bel_and_send_nothing(buses: tuple[can.BusABC, can.BusABC], line: bytes) -> None:
    side, peer = buses
    adapter = SlcanAdapter(side)
    adapter.handle_line(b"O")
    state = (adapter.is_open, adapter.listen_only, adapter.bitrate, adapter.timestamps)
    assert adapter.handle_line(line) == ERROR
    assert (adapter.is_open, adapter.listen_only, adapter.bitrate, adapter.timestamps) == state
    assert peer.recv(0.05) is None


def test_frames_only_while_open_and_timestamps(buses: tuple[can.BusABC, can.BusABC]) -> None:
    adapter = SlcanAdapter(buses[0])
    frame = can.Message(arbitration_id=0x181, is_extended_id=False, data=b"\x01\x02")
    assert adapter.frame_line(frame) is None
    assert adapter.handle_line(b"t1810") == ERROR
    assert adapter.handle_line(b"Z1") == OK
    adapter.handle_line(b"O")
    line = adapter.frame_line(frame)
    assert line is not None and line.startswith(b"t18120102") and len(line) == 9 + 4 + 1
    assert int(line[9:13], 16) < 60000


frames = st.builds(
    lambda ext, rtr, ident, data, dlc: can.Message(
        arbitration_id=ident & (0x1FFFFFFF if ext else 0x7FF),
        is_extended_id=ext,
        is_remote_frame=rtr,
        data=b"" if rtr else data,
        dlc=dlc if rtr else len(data),
    ),
    st.booleans(),
    st.booleans(),
    st.integers(0, 0x1FFFFFFF),
    st.binary(max_size=8),
    st.integers(0, 8),
)


@settings(max_examples=300, deadline=None)
@given(frame=frames)
def test_any_frame_survives_the_round_trip(frame: can.Message) -> None:
    channel = f"test-slcan-rt-{uuid.uuid4().hex}"
    side = can.Bus(interface="virtual", channel=channel)
    peer = can.Bus(interface="virtual", channel=channel)
    try:
        adapter = SlcanAdapter(side)
        adapter.handle_line(b"O")
        line = adapter.frame_line(frame)
        assert line is not None and line.endswith(OK) and line.isascii()
        adapter.handle_line(line[:-1])
        received = peer.recv(1.0)
        assert received is not None and same_frame(received, frame)
    finally:
        side.shutdown()
        peer.shutdown()


@settings(max_examples=500, deadline=None)
@given(
    line=st.binary(max_size=40)
    | st.text("tTrRSsOLCFVvNZMm0123456789ABCDEFabcdefG", max_size=30).map(str.encode)
)
def test_fuzzed_lines_never_crash(line: bytes) -> None:
    channel = f"test-slcan-fz-{uuid.uuid4().hex}"
    side = can.Bus(interface="virtual", channel=channel)
    peer = can.Bus(interface="virtual", channel=channel)
    try:
        adapter = SlcanAdapter(side)
        adapter.handle_line(b"O")
        reply = adapter.handle_line(line.replace(b"\r", b""))
        sent = peer.recv(0)
        if sent is None:
            assert reply in (OK, ERROR, b"") or reply[:1] in b"FVvN"
        else:  # only a well-formed transmit line sends; it re-encodes to itself, hex in upper case
            assert reply in (b"z\r", b"Z\r")
            encoded, given = adapter.frame_line(sent), line.replace(b"\r", b"") + OK
            assert encoded is not None and encoded[:1] == given[:1]
            assert encoded[1:] == given[1:].upper()
    finally:
        side.shutdown()
        peer.shutdown()


# -- python-can's slcan interface over the pty ----------------------------------------


@pytest.fixture
def pty_rig(buses: tuple[can.BusABC, can.BusABC]) -> Iterator[tuple[SlcanPty, can.BusABC]]:
    side, peer = buses
    adapter = SlcanPty(side).start()
    yield adapter, peer
    adapter.close()


def open_host(path: str) -> slcanBus:
    """Exactly how a host opens a USB SLCAN adapter (minus the 2 s settling sleep)."""
    return cast(slcanBus, can.Bus(interface="slcan", channel=path, bitrate=500000, sleep_after_open=0))


def recv_frame(bus: can.BusABC, timeout: float = 2.0) -> can.Message | None:
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        message = bus.recv(left)
        if message is not None:
            return message
    return None


def test_python_can_host_over_the_pty(pty_rig: tuple[SlcanPty, can.BusABC]) -> None:
    adapter, peer = pty_rig
    host = open_host(adapter.path)
    try:
        assert host.get_version(2.0) == (10, 13)
        assert host.get_serial_number(2.0) == "FS01"
        sent = [
            can.Message(arbitration_id=0x601, is_extended_id=False, data=bytes(range(8))),
            can.Message(arbitration_id=0x1234567, is_extended_id=True, data=b"\xff"),
            can.Message(arbitration_id=0x701, is_extended_id=False, is_remote_frame=True, dlc=1),
        ]
        for frame in sent:
            host.send(frame)
            received = peer.recv(2.0)
            assert received is not None and same_frame(received, frame)
        for frame in sent:
            peer.send(frame)
            received = recv_frame(host)
            assert received is not None and same_frame(received, frame)
    finally:
        host.shutdown()


def test_garbage_on_the_pty_is_harmless(pty_rig: tuple[SlcanPty, can.BusABC]) -> None:
    adapter, peer = pty_rig
    host = open_host(adapter.path)
    try:
        port = host.serialPortOrig
        port.write(b"\xff\xfe\x00garbage\r" + b"t" * 65536 + b"\rT\rt12\r\n\n\r")
        port.write(b"t3211AB\r")
        received = peer.recv(2.0)
        assert received is not None and (received.arbitration_id, bytes(received.data)) == (0x321, b"\xab")
        peer.send(can.Message(arbitration_id=0x185, is_extended_id=False, data=b"\x01"))
        received = recv_frame(host)  # the BEL replies before it are skipped by python-can
        assert received is not None and received.arbitration_id == 0x185
    finally:
        host.shutdown()


def test_unread_frames_overflow_without_blocking_and_a_new_session_starts_clean(
    pty_rig: tuple[SlcanPty, can.BusABC],
) -> None:
    adapter, peer = pty_rig
    adapter.adapter.handle_line(b"O")  # as if a host had opened and then stopped reading
    for i in range(20000):  # ~300 kB of lines: more than the pty and the queue hold
        peer.send(
            can.Message(arbitration_id=0x180 + i % 64, is_extended_id=False, data=i.to_bytes(4, "little"))
        )
    deadline = time.monotonic() + 5.0
    while not adapter.adapter.flags & FLAG_DATA_OVERRUN and time.monotonic() < deadline:
        time.sleep(0.01)
    assert adapter.adapter.flags & FLAG_DATA_OVERRUN
    host = open_host(adapter.path)  # its C drops the stale backlog
    try:
        time.sleep(0.1)
        marker = can.Message(arbitration_id=0x7AB, is_extended_id=False, data=b"\x42")
        peer.send(marker)
        received = recv_frame(host)
        assert received is not None and same_frame(received, marker)
    finally:
        host.shutdown()
