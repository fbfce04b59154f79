"""The CANopen node in firmware_sim, driven by a plain ``canopen`` master over a virtual bus.

The firmware runs on a virtual clock that the tests tick by hand, so step
counts are exact: the firmware's own counter is the reference.
"""

from __future__ import annotations

import itertools
import struct
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import can
import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from feeder.plant.amplifier import AmplifierLimits
from feeder.protocol.eds import MODES, STATUS_WORD_BITS, object_dictionary
from firmware_sim.canopen_node import CanopenNode, error_register
from firmware_sim.clock import VirtualClock
from firmware_sim.faults import Fault
from firmware_sim.firmware import Firmware, FirmwareConfig

pytestmark = pytest.mark.timeout(60)
NODE_ID = 5
STATUS_MOVING, STATUS_STEPPING_MODE, STATUS_FAULT, STATUS_REFUSED = (
    1 << STATUS_WORD_BITS.index(name) for name in ("moving", "stepping mode", "fault", "refused")
)


@dataclass
class Rig:
    firmware: Firmware
    clock: VirtualClock
    node: CanopenNode
    master: canopen.RemoteNode
    network: canopen.Network
    channel: str

    def run(self, seconds: float) -> None:
        """Advance the firmware by ``seconds`` of virtual time."""
        self.firmware.run(self.clock, max_ticks=round(seconds * self.firmware.config.tick_hz))

    def tpdo_until(self, predicate: Callable[[canopen.pdo.PdoMap], bool]) -> canopen.pdo.PdoMap:
        """The first TPDO1 satisfying ``predicate`` (fails after 5 s without one)."""
        tpdo = self.master.tpdo[1]
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            if tpdo.is_received and predicate(tpdo):
                return tpdo
            tpdo.wait_for_reception(0.2)
        pytest.fail("no matching TPDO1")


def wait_emcy(master: canopen.RemoteNode, code: int) -> canopen.emcy.EmcyError:
    """The first EMCY with ``code`` in the master's log (fails after 3 s without one)."""
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline:
        for emcy in list(master.emcy.log):
            if emcy.code == code:
                return emcy
        time.sleep(0.01)
    pytest.fail(f"no EMCY 0x{code:04X}")


def make_rig(config: FirmwareConfig | None = None) -> Iterator[Rig]:
    channel = f"test-can-node-{uuid.uuid4().hex}"
    firmware = Firmware(config)
    clock = VirtualClock()
    node = CanopenNode(firmware, 1, NODE_ID, can.Bus(interface="virtual", channel=channel))
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.1
    network.connect(interface="virtual", channel=channel)
    master = canopen.RemoteNode(NODE_ID, object_dictionary(NODE_ID))
    master.sdo.RESPONSE_TIMEOUT = 1.0
    network.add_node(master)
    node.start()
    master.tpdo.read(from_od=True)
    master.rpdo.read(from_od=True)
    yield Rig(firmware, clock, node, master, network, channel)
    network.disconnect()
    node.close()


@pytest.fixture
def rig() -> Iterator[Rig]:
    yield from make_rig()


def snapshot(rig: Rig) -> tuple[object, ...]:
    """Everything a refused write must leave alone: axis state and SDO read-backs."""
    sdo = rig.master.sdo
    return (
        rig.firmware.axis(1).status(),
        sdo["Frequency"].raw,
        sdo["Amplitude"].raw,
        sdo["Flyback shape"].raw,
        sdo["Flyback time"].raw,
        sdo["Mode"].raw,
        sdo["Producer heartbeat time"].raw,
        sdo["TPDO1 communication parameter"][2].raw,
    )


def test_identity_matches_the_eds_and_the_firmware_serial(rig: Rig) -> None:
    od = object_dictionary(NODE_ID)
    identity = rig.master.sdo["Identity object"]
    assert identity["Vendor-ID"].raw == od.device_information.vendor_number
    assert identity["Product code"].raw == od.device_information.product_number
    assert identity["Revision number"].raw == od.device_information.revision_number
    assert identity["Serial number"].raw == int(rig.firmware.config.serial_number[2:])
    # A string longer than 4 bytes: segmented upload.
    assert rig.master.sdo["Manufacturer device name"].raw == "feeder stick-slip amplifier"
    assert rig.master.sdo["Device type"].raw == 0


def test_settings_by_sdo_reach_the_firmware(rig: Rig) -> None:
    sdo = rig.master.sdo
    sdo["Frequency"].raw = 1_234_500
    sdo["Amplitude"].raw = 42_000
    sdo["Flyback time"].raw = 50_000
    sdo["Flyback shape"].raw = 0
    sdo["Mode"].raw = MODES.index("stp")
    status = rig.firmware.axis(1).status()
    assert status.frequency_hz == pytest.approx(1234.5)
    assert status.amplitude_v == pytest.approx(42.0)
    assert (status.flyback_shape, status.flyback_s) == ("linear", pytest.approx(50e-6))
    assert status.mode == "stp"
    assert (sdo["Frequency"].raw, sdo["Amplitude"].raw, sdo["Flyback time"].raw) == (
        1_234_500,
        42_000,
        50_000,
    )
    assert sdo["Amplitude limit"].raw == round(AmplifierLimits().max_amplitude_vpp * 1000)
    # the other front end (the console) calls the same API: the node sees its settings
    rig.firmware.axis(1).set_flyback("half-cosine", 200e-6)
    rig.firmware.axis(1).set_frequency(250.0)
    assert (sdo["Flyback shape"].raw, sdo["Flyback time"].raw, sdo["Frequency"].raw) == (1, 200_000, 250_000)


def test_steps_by_sdo_and_rpdo_advance_the_counter_exactly(rig: Rig) -> None:
    sdo = rig.master.sdo
    sdo["Frequency"].raw = 1_000_000
    sdo["Amplitude"].raw = 30_000
    sdo["Mode"].raw = MODES.index("stp")
    rig.master.nmt.state = "OPERATIONAL"  # motion starts in OPERATIONAL only
    sdo["Step command"].raw = 37
    rig.run(0.2)
    assert rig.firmware.axis(1).status().step_counter == 37
    assert sdo["Step counter"].raw == 37

    rpdo = rig.master.rpdo[1]
    rpdo["Step command"].raw = -120
    rpdo["Command sequence"].raw = 9
    rpdo.transmit()
    tpdo = rig.tpdo_until(lambda p: p["Command acknowledge"].raw == 9)
    assert int(tpdo["Status word"].raw) & STATUS_MOVING
    assert not int(tpdo["Status word"].raw) & STATUS_REFUSED
    rig.run(0.3)
    assert rig.firmware.axis(1).status().step_counter == 37 - 120
    tpdo = rig.tpdo_until(lambda p: p["Step counter"].raw == 37 - 120)
    assert tpdo["Status word"].raw == STATUS_STEPPING_MODE


def test_rpdo_zero_stops_and_a_refused_rpdo_is_flagged(rig: Rig) -> None:
    sdo = rig.master.sdo
    sdo["Mode"].raw = MODES.index("stp")
    rig.master.nmt.state = "OPERATIONAL"
    rpdo = rig.master.rpdo[1]
    rpdo["Step command"].raw = 1000
    rpdo["Command sequence"].raw = 1
    rpdo.transmit()
    rig.tpdo_until(lambda p: p["Command acknowledge"].raw == 1)
    rig.run(0.05)
    rpdo["Step command"].raw = 0
    rpdo["Command sequence"].raw = 2
    rpdo.transmit()
    rig.tpdo_until(lambda p: p["Command acknowledge"].raw == 2)
    counter = rig.firmware.axis(1).status().step_counter
    rig.run(0.2)
    assert 0 < rig.firmware.axis(1).status().step_counter == counter < 1000

    sdo["Mode"].raw = MODES.index("gnd")
    rpdo["Step command"].raw = 10
    rpdo["Command sequence"].raw = 3
    rpdo.transmit()
    tpdo = rig.tpdo_until(lambda p: p["Command acknowledge"].raw == 3)
    assert int(tpdo["Status word"].raw) & STATUS_REFUSED
    assert not rig.firmware.axis(1).status().moving


@pytest.mark.parametrize(
    ("name", "value", "code"),
    [
        ("Frequency", 2_000_001, 0x06090031),  # EDS HighLimit
        ("Frequency", 999, 0x06090032),  # EDS LowLimit
        ("Amplitude", 200_001, 0x06090031),
        ("Flyback shape", 3, 0x06090031),  # 'custom' is read-only
        ("Mode", 7, 0x06090031),
        ("Continuous", -2, 0x06090032),
        ("Step command", -(1 << 31), 0x06090032),
        ("Step counter", 5, 0x06010002),  # read-only
        ("Amplitude limit", 1, 0x06010002),
        ("Fault word", 0, 0x06010002),
        ("Step command", 10, 0x08000022),  # axis grounded
        ("Continuous", 1, 0x08000022),
    ],
)
def test_bad_writes_abort_with_the_right_code_and_change_nothing(
    rig: Rig, name: str, value: int, code: int
) -> None:
    before = snapshot(rig)
    with pytest.raises(SdoAbortedError) as info:
        rig.master.sdo[name].raw = value
    assert info.value.code == code
    assert snapshot(rig) == before


def test_tighter_firmware_limits_and_conflicts_abort_too() -> None:
    config = FirmwareConfig(amplifier=AmplifierLimits(v_max_v=100.0, max_frequency_hz=500.0))
    for rig in make_rig(config):
        sdo = rig.master.sdo
        sdo["Frequency"].raw = 400_000  # period 2.5 ms
        sdo["Flyback time"].raw = 2_000_000  # 2 ms
        sdo["Flyback shape"].raw = 0  # linear: fits the period
        before = snapshot(rig)
        for name, value, code in [
            ("Amplitude", 150_000, 0x06090031),  # inside the EDS, above this rating
            ("Frequency", 600_000, 0x06090031),  # inside the EDS, above this amplifier
            ("Frequency", 500_000, 0x06040043),  # period 2 ms: the flyback no longer fits
        ]:
            with pytest.raises(SdoAbortedError) as info:
                sdo[name].raw = value
            assert info.value.code == code
            assert snapshot(rig) == before


def test_unknown_objects_and_access_errors(rig: Rig) -> None:
    before = snapshot(rig)
    for call, code in [
        (lambda: rig.master.sdo.upload(0x2100, 0), 0x06020000),
        (lambda: rig.master.sdo.download(0x5FFF, 0, b"\x01\x00\x00\x00"), 0x06020000),
        (lambda: rig.master.sdo.upload(0x1018, 9), 0x06090011),
        (lambda: rig.master.sdo["Continuous"].raw, 0x06010001),
        (lambda: rig.master.sdo.download(0x2000, 0, b"\x01\x02"), 0x06070010),
        (lambda: rig.master.sdo.download(0x1800, 2, b"\xf8"), 0x06090030),  # type 248
    ]:
        with pytest.raises(SdoAbortedError) as info:
            call()
        assert info.value.code == code
    assert snapshot(rig) == before


def test_nmt_stopped_node_is_silent_but_beats(rig: Rig) -> None:
    rig.master.sdo["Mode"].raw = MODES.index("stp")
    rig.master.nmt.state = "OPERATIONAL"
    rig.master.sdo["Continuous"].raw = 1
    rig.run(0.05)
    assert rig.firmware.axis(1).status().moving
    rig.master.nmt.state = "STOPPED"
    assert rig.master.nmt.wait_for_heartbeat(2.0) == "STOPPED"
    rig.run(0.05)  # the DAC plays out its buffer
    assert not rig.firmware.axis(1).status().moving  # leaving OPERATIONAL stopped it
    rig.master.sdo.RESPONSE_TIMEOUT = 0.3
    rig.master.sdo.MAX_RETRIES = 1
    with pytest.raises(SdoCommunicationError):
        _ = rig.master.sdo["Frequency"].raw
    rig.master.nmt.state = "PRE-OPERATIONAL"
    assert rig.master.sdo["Mode"].raw == MODES.index("stp")


def test_reset_node_boots_grounded_with_eds_defaults(rig: Rig) -> None:
    sdo = rig.master.sdo
    sdo["Mode"].raw = MODES.index("stp")
    sdo["Producer heartbeat time"].raw = 50
    sdo["TPDO1 communication parameter"][5].raw = 7
    states: list[int] = []
    rig.master.nmt.add_heartbeat_callback(states.append)
    rig.master.nmt.state = "RESET"
    deadline = time.monotonic() + 3.0
    while (0 not in states or 127 not in states[states.index(0) :]) and time.monotonic() < deadline:
        time.sleep(0.01)
    boot = states.index(0)  # the boot-up message ...
    assert states[boot + 1] == 127  # ... then PRE-OPERATIONAL heartbeats
    assert rig.firmware.axis(1).status().mode == "gnd"
    assert sdo["Producer heartbeat time"].raw == 100
    assert sdo["TPDO1 communication parameter"][5].raw == 100


def test_heartbeat_period_follows_object_0x1017(rig: Rig) -> None:
    stamps: list[float] = []
    rig.master.sdo["Producer heartbeat time"].raw = 20
    rig.master.nmt.add_heartbeat_callback(lambda state: stamps.append(time.monotonic()))
    deadline = time.monotonic() + 5.0
    while len(stamps) < 11 and time.monotonic() < deadline:
        time.sleep(0.01)
    intervals = sorted(b - a for a, b in itertools.pairwise(stamps))
    # median of 10 intervals: robust to a starved thread; the default would give 0.1 s
    assert len(intervals) >= 10 and intervals[len(intervals) // 2] < 0.05


def test_fault_raises_emcy_and_clearing_resets_it(rig: Rig) -> None:
    rig.master.sdo["Mode"].raw = MODES.index("stp")
    rig.master.emcy.reset()
    rig.firmware.axis(1).inject_fault(Fault.OVERTEMP)
    emcy = wait_emcy(rig.master, 0x4200)
    assert emcy.register == error_register(int(Fault.OVERTEMP)) == 0x09
    assert struct.unpack_from("<I", emcy.data)[0] == Fault.OVERTEMP
    assert rig.master.sdo["Fault word"].raw == Fault.OVERTEMP
    assert int(rig.master.sdo["Status word"].raw) & STATUS_FAULT
    assert rig.master.sdo["Error register"].raw == 0x09
    assert rig.master.sdo["Mode"].raw == MODES.index("gnd")
    with pytest.raises(SdoAbortedError) as info:
        rig.master.sdo["Mode"].raw = MODES.index("stp")
    assert info.value.code == 0x08000022
    rig.master.sdo["Fault reset"].raw = 1
    wait_emcy(rig.master, 0x0000)
    assert rig.master.sdo["Error register"].raw == 0


def test_sync_driven_tpdo_every_second_sync(rig: Rig) -> None:
    rig.master.sdo["TPDO1 communication parameter"][2].raw = 2
    rig.master.nmt.state = "OPERATIONAL"
    received: list[bytes] = []
    rig.master.tpdo[1].add_callback(lambda pdo: received.append(bytes(pdo.data)))
    time.sleep(0.2)
    assert received == []  # no event-driven TPDOs in SYNC mode
    for _ in range(10):
        rig.network.sync.transmit()
    deadline = time.monotonic() + 3.0
    while len(received) < 5 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.1)
    assert len(received) == 5


def test_short_rpdo_raises_emcy_and_does_nothing(rig: Rig) -> None:
    rig.master.sdo["Mode"].raw = MODES.index("stp")
    rig.master.nmt.state = "OPERATIONAL"
    rig.master.emcy.reset()
    rig.network.send_message(0x200 + NODE_ID, b"\x10\x00")
    wait_emcy(rig.master, 0x8210)
    assert not rig.firmware.axis(1).status().moving


def harmless(can_id: int, data: bytes) -> bool:
    """Frames that must not change anything: all but valid NMT commands for this
    node, well-formed SDO requests to it and its RPDO (those are commands)."""
    if can_id == 0x000:
        return len(data) < 2 or data[1] not in (0, NODE_ID) or data[0] not in (1, 2, 128, 129, 130)
    if can_id == 0x600 + NODE_ID:
        return len(data) != 8
    return can_id != 0x200 + NODE_ID


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    frames=st.lists(
        st.tuples(
            st.sampled_from([0x000, 0x080, 0x600 + NODE_ID, 0x7E5]) | st.integers(0, 0x7FF),
            st.binary(max_size=8),
        ),
        max_size=20,
    )
)
def test_random_and_malformed_frames_do_no_harm(rig: Rig, frames: list[tuple[int, bytes]]) -> None:
    before = snapshot(rig)
    for can_id, data in frames:
        if harmless(can_id, data):
            rig.network.send_message(can_id, data)
    assert snapshot(rig) == before
    assert rig.node.nmt_state == 127
