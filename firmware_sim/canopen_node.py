"""Firmware axes as a CANopen (CiA 301) node: the CAN front end of the amplifier.

The node is the ``canopen`` package's :class:`canopen.LocalNode` (object
dictionary from an EDS in :mod:`feeder.protocol.eds`, NMT slave, heartbeat
producer, EMCY producer) with the amplifier behind its read/write hooks and
objects addressed by their EDS names.  It serves as many axes as its EDS lists
(one, or three for ``feeder_amplifier_3axis.eds``), each through an
:class:`~firmware_sim.canopen_axis.AxisPort` with its own objects and PDOs; NMT,
heartbeat, SDO, EMCY and the error register are the node's.  It calls the same
:class:`firmware_sim.axis.Axis` API as the ANC300 console: one amplifier,
two front ends.

Frames are handled when they arrive, in the thread that delivers them: on a
:class:`~firmware_sim.can_wire.CanWire` (:func:`firmware_sim.__main__.serve_slcan_pty`)
that is the adapter's pty thread, like a CAN receive interrupt; on any other python-can bus
the network's receive thread.  Each SDO request, NMT command, SYNC and RPDO is
handled whole under the firmware's lock, so it sees (and leaves) one consistent
state between two ticks, and every write goes through the axis' limits and
safety state machine.

What this module adds to ``LocalNode``:

- SDO writes outside the EDS's LowLimit/HighLimit abort with 0x06090031 (too
  high) / 0x06090032 (too low); values the firmware refuses abort with the same
  codes when the firmware's own limit is tighter (e.g. a lower amplitude rating),
  0x06040043 when they conflict with another setting (flyback longer than half
  a period), 0x08000022 when the axis' or the node's state forbids them (stepping
  while grounded or in fault; starting motion, ``Step command`` or ``Continuous``
  not 0, outside OPERATIONAL).  A refused write changes nothing.  Unknown objects
  (0x06020000), sub-indices (0x06090011), read-only (0x06010002) and write-only
  (0x06010001) objects and client aborts follow CiA 301
  (:mod:`firmware_sim.sdo_server`).
- Frames: CiA 301's only, 11-bit data frames; 29-bit, remote and error frames are
  ignored (:mod:`feeder.protocol.can_frames`), whichever identifier they carry.
- NMT: the five commands of CiA 301 (others are ignored); SDO served in
  PRE-OPERATIONAL and OPERATIONAL only; PDOs, and motion started by SDO, in
  OPERATIONAL only; any state but OPERATIONAL stops every axis; reset node / reset
  communication restore the EDS defaults (reset node also grounds every axis),
  send the boot-up message and enter PRE-OPERATIONAL.
- TPDOn of axis n (step counter, status word, command acknowledge, the node's
  error register): transmission type 254/255 sends on change (no faster than
  the inhibit time) and at least every event-timer period, and once on entering
  OPERATIONAL (unless ``tpdo_on_start`` is False: CiA 301 does not require it);
  type 1..240 sends on every n-th SYNC.  The step counter (I32, in the TPDO and by
  SDO) wraps in two's complement past ±2³¹, as a drive's counter does.
- RPDOn of axis n (step command, command sequence): ``+N``/``-N`` starts a burst,
  0 stops; the sequence is echoed in TPDOn's command acknowledge, with status
  bit 3 set when the firmware refused the command.  A too-short RPDO raises EMCY
  0x8210.
- EMCY when a fault bit of an axis latches (code per fault, error register,
  fault word in bytes 3..6, the axis' number in the node in byte 7), and EMCY
  0x0000 when that axis' fault word is cleared.
- Heartbeat consumer (0x1016:1, producer id << 16 | ms): the host's heartbeats
  count as host activity; once one has arrived, none for the set time latches
  the firmware's ``host_watchdog`` fault on every moving axis (grounded, EMCY
  0x8130).  Monitoring restarts with the next heartbeat.
- A sampling cycle (TPDOs, EMCY, heartbeat consumer) that fails is logged and
  grounds the node's axes; the node goes on (:meth:`CanopenNode._run`).
"""

from __future__ import annotations

import functools
import logging
import re
import struct
import threading
import time
import zlib
from collections.abc import Callable, Sequence
from typing import Any

import can
import canopen
from canopen.objectdictionary import ObjectDictionary, ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from feeder.errors import InputError
from feeder.protocol.can_frames import CanopenFrames, is_canopen_frame
from feeder.protocol.eds import axis_count, object_dictionary
from firmware_sim.axis import AxisStatus
from firmware_sim.can_wire import WireBus
from firmware_sim.canopen_axis import MOTION_OBJECTS, AxisPort
from firmware_sim.faults import Fault, FirmwareError, LimitError
from firmware_sim.firmware import Firmware
from firmware_sim.sdo_server import SdoServer

log = logging.getLogger(__name__)

NMT_OPERATIONAL = 5
NMT_PRE_OPERATIONAL = 127
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82
NMT_ENTER_PRE_OPERATIONAL = 0x80
NMT_COMMANDS = (0x01, 0x02, NMT_ENTER_PRE_OPERATIONAL, NMT_RESET_NODE, NMT_RESET_COMMUNICATION)
"""CiA 301's NMT commands (start, stop, enter PRE-OPERATIONAL, reset node, reset
communication); the node ignores any other."""
SYNC_COB_ID = 0x80

ABORT_RANGE = 0x06090030
ABORT_TOO_HIGH = 0x06090031
ABORT_TOO_LOW = 0x06090032
ABORT_INCOMPATIBLE = 0x06040043
ABORT_DEVICE_STATE = 0x08000022

EMCY_CODES = {Fault.WATCHDOG: 0x6010, Fault.HOST_WATCHDOG: 0x8130, Fault.OVERTEMP: 0x4200}
"""EMCY error code per fault bit (CiA 301: software reset/watchdog, life guard,
device temperature); other bits send 0x1000 (generic)."""
EMCY_PDO_LENGTH = 0x8210
ERROR_REGISTER_BITS = {Fault.WATCHDOG: 0x80, Fault.HOST_WATCHDOG: 0x10, Fault.OVERTEMP: 0x08}
"""Object 0x1001 bits besides bit 0 (generic): manufacturer, communication, temperature."""

LIMIT_FIELDS = {
    "Frequency": "frequency",
    "Amplitude": "voltage",
    "Flyback time": "flyback",
    "Offset": "offset",
    "Step command": "steps",
}
"""The firmware's name (``LimitError.field``) of the value each object sets."""

IDLE_POLL_S = 0.01
"""How often a node without event-driven PDOs to send (not OPERATIONAL, or TPDOs on
SYNC) samples its axes for EMCY and the heartbeat consumer."""

CONSUMER_HEARTBEAT = "Consumer heartbeat time.Consumer heartbeat time 1"


def error_register(fault_word: int) -> int:
    """Object 0x1001 for a fault word: bit 0 on any fault, plus the class bits."""
    if not fault_word:
        return 0
    register = 0x01
    for bit, mask in ERROR_REGISTER_BITS.items():
        if fault_word & bit:
            register |= mask
    return register


def serial_number_u32(serial: str) -> int:
    """Object 0x1018:4 from the firmware's serial string: its digits, else a CRC-32."""
    digits = re.sub(r"\D", "", serial)
    return int(digits) & 0xFFFFFFFF if digits else zlib.crc32(serial.encode())


class CanopenNode:
    """Axes ``axes`` of ``firmware`` as CANopen node ``node_id`` on ``bus``.

    ``axes``: the firmware axis numbers the node serves, in the order of its EDS's
    axes (one number for the one-axis EDS; as many as the EDS lists).
    ``bus``: an endpoint of a :class:`~firmware_sim.can_wire.CanWire` (frames
    handled in the sender's thread) or any python-can bus (a receive thread).
    ``od``: the object dictionary (default: the packaged one-axis EDS).
    ``start()`` boots the node (boot-up message, PRE-OPERATIONAL, heartbeat);
    ``close()`` stops it and shuts the bus down.  ``poll_s`` is how often the
    node samples its axes for event-driven TPDOs and EMCY.  ``operational_with_errors``
    False: as CANopenNode with ``CO_NMT_ERR_ON_ERR_REG`` (its examples' default), the node
    leaves OPERATIONAL for PRE-OPERATIONAL while its error register is set (its outputs
    left as they are), so a start does not hold until the faults are cleared.
    ``tpdo_on_start`` False: entering OPERATIONAL sends no TPDO (CiA 301 does not ask for
    one); event-driven TPDOs then go out on a change or when their event timer expires.
    """

    def __init__(
        self,
        firmware: Firmware,
        axes: int | Sequence[int],
        node_id: int,
        bus: can.BusABC,
        od: ObjectDictionary | None = None,
        poll_s: float = 0.001,
        operational_with_errors: bool = True,
        tpdo_on_start: bool = True,
    ) -> None:
        self.firmware = firmware
        self.node_id = node_id
        self.poll_s = poll_s
        self.operational_with_errors = operational_with_errors
        self.tpdo_on_start = tpdo_on_start
        od = od if od is not None else object_dictionary(node_id)
        numbers = (axes,) if isinstance(axes, int) else tuple(axes)
        if len(numbers) != axis_count(od):
            raise InputError("axes", f"the node's EDS has {axis_count(od)} axes, given {len(numbers)}")
        self.local = canopen.LocalNode(node_id, od)
        self.local.sdo = SdoServer(self.local)
        self.ports = [AxisPort(od, firmware.axis(a), n) for n, a in enumerate(numbers, start=1)]
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = 0.1  # close() waits at most this long for the receiver
        self._tpdo_lock = threading.Lock()
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"canopen-node-{node_id}")
        self._consumer_id = 0  # host whose heartbeat is consumed; 0 = none
        self._consumer_timeout_s = 0.0
        self._consumer_seen: float | None = None
        self._writers: dict[str, tuple[AxisPort | None, Callable[[int], None]]] = {
            CONSUMER_HEARTBEAT: (None, self._write_consumer_heartbeat)
        }
        self._objects: dict[str, AxisPort] = {}
        for port in self.ports:
            self._writers.update({name: (port, writer) for name, writer in port.writers.items()})
            self._objects.update({name: port for name in port.base})
        for name in ("Error register", "Identity object", CONSUMER_HEARTBEAT):
            od[name]  # a name the EDS lacks fails here, not on the first request

    @property
    def axis(self) -> Any:
        """The firmware axis of a one-axis node (its first axis otherwise)."""
        return self.ports[0].axis

    @property
    def nmt_state(self) -> int:
        """NMT state code: 0 initialising, 4 stopped, 5 operational, 127 pre-operational."""
        return int(self.local.nmt._state)

    # -- life cycle -------------------------------------------------------------

    def start(self) -> CanopenNode:
        local, network = self.local, self.network
        network.add_node(local)
        network.unsubscribe(local.sdo.rx_cobid, local.sdo.on_request)
        network.subscribe(local.sdo.rx_cobid, self._on_sdo)
        network.unsubscribe(0, local.nmt.on_command)
        network.subscribe(0, self._on_nmt)
        network.subscribe(SYNC_COB_ID, self._on_sync)
        local.add_read_callback(self._on_read)
        local.add_write_callback(self._on_write)
        local.tpdo.read(from_od=True)
        local.rpdo.read(from_od=True)
        for port in self.ports:
            tpdo = local.tpdo[port.number]
            port.tpdo_cob_id = tpdo.cob_id
            # the TPDO's layout from its mapping (byte-aligned, as in the EDS): packed with
            # struct, not through canopen's PDO variables, on every SYNC / change
            port.tpdo_layout = [(v.od.qualname, v.od.STRUCT_TYPES[v.od.data_type]) for v in tpdo.map]
            local.rpdo[port.number].add_callback(functools.partial(self._on_rpdo, port))
        bus = network.bus
        if isinstance(bus, WireBus):  # frames handled in the sender's thread, as they arrive
            bus.receiver = self._receive
        else:
            network.listeners = [CanopenFrames(network)]
            network.connect()
        self._boot(reset_application=False)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the node (no more heartbeats: the host sees it vanish)."""
        self._stopping.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self.local.nmt.stop_heartbeat()
        self.network.disconnect()

    def __enter__(self) -> CanopenNode:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _boot(self, reset_application: bool) -> None:
        """Restore defaults, send the boot-up message and enter PRE-OPERATIONAL."""
        store = self.local.data_store
        for index in list(store):
            if reset_application or index < 0x2000:
                del store[index]
        for port in self.ports:
            port.reset(reset_application)
        self._consume_heartbeat(0, 0.0)
        self.local.nmt.send_command(0x81)  # state INITIALISING: boot-up message
        self.local.nmt.send_command(NMT_ENTER_PRE_OPERATIONAL)  # starts the heartbeat

    # -- CAN services (each handled whole under the firmware's lock) -------------

    def _receive(self, msg: can.Message) -> None:
        """A frame from the wire, in the sender's thread."""
        if is_canopen_frame(msg):
            self.network.notify(msg.arbitration_id, msg.data, msg.timestamp)

    def _on_sdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.nmt_state in (NMT_PRE_OPERATIONAL, NMT_OPERATIONAL) and len(data) == 8:
            with self.firmware.lock:
                self.firmware.host_activity()
                self.local.sdo.on_request(can_id, data, timestamp)
            self._wake.set()

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id) or data[0] not in NMT_COMMANDS:
            return
        with self.firmware.lock:
            if canopen.nmt.COMMAND_TO_STATE[data[0]] != NMT_OPERATIONAL:
                for port in self.ports:
                    port.axis.stop()  # before the heartbeat announces the new state
            self.local.nmt.on_command(can_id, data, timestamp)
            if data[0] in (NMT_RESET_NODE, NMT_RESET_COMMUNICATION):
                self._boot(reset_application=data[0] == NMT_RESET_NODE)
        self._wake.set()

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.nmt_state != NMT_OPERATIONAL:
            return
        statuses: dict[int, AxisStatus] | None = None
        for port in self.ports:
            if not 1 <= port.tpdo_type <= 240:
                continue
            port.sync_count += 1
            if port.sync_count % port.tpdo_type == 0:
                statuses = statuses or self._statuses()
                self._send_tpdo(port, statuses[port.number], self._register(statuses))

    def _on_rpdo(self, port: AxisPort, pdo: Any) -> None:
        if self.nmt_state != NMT_OPERATIONAL:
            return
        if len(pdo.data) * 8 < pdo.length:
            self.local.emcy.send(EMCY_PDO_LENGTH, self._register(self._statuses()))
            return
        with self.firmware.lock:
            self.firmware.host_activity()
            count = int(pdo[port.step_command].raw)
            try:
                port.write_step_command(count)
                port.refused = False
            except FirmwareError:
                port.refused = True
            port.ack = int(pdo[port.command_sequence].raw)
        self._wake.set()

    def _statuses(self) -> dict[int, AxisStatus]:
        """Every axis' status, by its number in the node."""
        return {port.number: port.axis.status() for port in self.ports}

    @staticmethod
    def _register(statuses: dict[int, AxisStatus]) -> int:
        """The node's error register: every axis' faults."""
        word = 0
        for status in statuses.values():
            word |= status.fault_word
        return error_register(word)

    # -- object dictionary hooks ------------------------------------------------

    def _on_read(self, index: int, subindex: int, od: ODVariable) -> int | None:
        name = od.qualname
        if name == "Identity object.Serial number":
            return serial_number_u32(self.firmware.config.serial_number)
        if name == "Error register":
            return self._register(self._statuses())
        port = self._objects.get(name)
        if port is None:
            return None
        if port.base[name] == "Amplitude limit":
            return round(self.firmware.config.amplifier.max_amplitude_vpp * 1000)
        return port.read(port.base[name], lambda: self._register(self._statuses()))

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        value = od.decode_raw(data)
        if not isinstance(value, int):
            return
        if od.min is not None and value < od.min:
            raise SdoAbortedError(ABORT_TOO_LOW)
        if od.max is not None and value > od.max:
            raise SdoAbortedError(ABORT_TOO_HIGH)
        port, writer = self._writers.get(od.qualname, (None, None))
        if writer is None:
            return
        base = port.base.get(od.qualname, od.qualname) if port is not None else od.qualname
        if value and base in MOTION_OBJECTS and self.nmt_state != NMT_OPERATIONAL:
            raise SdoAbortedError(ABORT_DEVICE_STATE)
        try:
            writer(value)
        except LimitError as exc:
            if exc.field != LIMIT_FIELDS.get(base):
                raise SdoAbortedError(ABORT_INCOMPATIBLE) from exc
            raise SdoAbortedError(ABORT_TOO_HIGH if exc.value > exc.hi else ABORT_TOO_LOW) from exc
        except FirmwareError as exc:
            raise SdoAbortedError(ABORT_DEVICE_STATE) from exc

    def _write_consumer_heartbeat(self, value: int) -> None:
        """0x1016:1 = producer id << 16 | ms; 0 ms switches the consumer off."""
        producer, milliseconds = value >> 16 & 0xFF, value & 0xFFFF
        if value >> 23 or (milliseconds and not 1 <= producer <= 127):
            raise SdoAbortedError(ABORT_RANGE)
        self._consume_heartbeat(producer if milliseconds else 0, milliseconds / 1000)

    def _consume_heartbeat(self, producer: int, timeout_s: float) -> None:
        """Watch node ``producer``'s heartbeat (0 = nobody)."""
        if self._consumer_id:
            self.network.unsubscribe(0x700 + self._consumer_id, self._on_host_heartbeat)
        self._consumer_id, self._consumer_timeout_s = producer, timeout_s
        self._consumer_seen = None
        if producer:
            self.network.subscribe(0x700 + producer, self._on_host_heartbeat)

    def _on_host_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self._consumer_seen = time.monotonic()
        self.firmware.host_activity()

    # -- TPDOs and EMCY ---------------------------------------------------------

    def _send_tpdo(self, port: AxisPort, status: AxisStatus, register: int) -> None:
        with self._tpdo_lock:
            self.network.send_message(port.tpdo_cob_id, port.pack_tpdo(status, register))

    def _report_faults(self, port: AxisPort, fault_word: int, register: int) -> None:
        new = fault_word & ~port.fault_reported
        detail = struct.pack("<IB", fault_word, port.number)
        for bit in Fault:
            if new & bit:
                self.local.emcy.send(EMCY_CODES.get(bit, 0x1000), register, detail)
        if port.fault_reported and not fault_word:
            self.local.emcy.reset(register, detail)
        port.fault_reported = fault_word

    def _run(self) -> None:
        """Sample the axes every ``poll_s`` (every :data:`IDLE_POLL_S` while no PDOs
        flow): EMCY on fault changes, each axis' TPDO when due.

        A sampling cycle that fails is logged (the first of a run of failures, with its
        traceback) and the loop goes on.  Such a cycle sent no TPDO or EMCY and may not
        have run the heartbeat consumer, so no one supervises the motion: as a drive's
        firmware does when its supervision task faults, the node grounds its axes (the
        safe state; the host sees ``gnd`` and must select a stepping mode again).
        """
        failures = 0
        while not self._stopping.is_set():
            pdos_flow = self.nmt_state == NMT_OPERATIONAL and any(p.tpdo_type >= 254 for p in self.ports)
            self._wake.wait(self.poll_s if pdos_flow else max(self.poll_s, IDLE_POLL_S))
            self._wake.clear()
            try:
                self._sample()
            except Exception:  # the thread's one boundary: any failure, not only foreseen ones
                if not failures:
                    log.exception("CANopen node %d: sampling failed; its axes are grounded", self.node_id)
                failures += 1
                for port in self.ports:
                    port.axis.ground()
            else:
                if failures:
                    log.warning(
                        "CANopen node %d: sampling works again after %d failures", self.node_id, failures
                    )
                failures = 0

    def _sample(self) -> None:
        """One sampling cycle: the heartbeat consumer, EMCY on fault changes, due TPDOs."""
        with self.firmware.lock:  # one instant, as a drive samples: an RPDO handled between
            # the statuses and the packing would pair its acknowledge with the status before it
            statuses = self._statuses()
            seen = self._consumer_seen
            if seen is not None and time.monotonic() - seen > self._consumer_timeout_s:
                self._consumer_seen = None  # one event per silence
                for port in self.ports:
                    if statuses[port.number].moving:
                        port.axis.inject_fault(Fault.HOST_WATCHDOG)
                statuses = self._statuses()
            register = self._register(statuses)
            packed = {port.number: port.pack_tpdo(statuses[port.number], register) for port in self.ports}
        state = self.nmt_state
        if register and state == NMT_OPERATIONAL and not self.operational_with_errors:
            self.local.nmt.send_command(NMT_ENTER_PRE_OPERATIONAL)
            state = NMT_PRE_OPERATIONAL
        reports = state in (NMT_PRE_OPERATIONAL, NMT_OPERATIONAL)
        for port in self.ports:
            status = statuses[port.number]
            if reports and status.fault_word != port.fault_reported:
                self._report_faults(port, status.fault_word, register)
            if state != NMT_OPERATIONAL or port.tpdo_type < 254:
                port.last_data = None
                continue
            now = time.monotonic()
            with self._tpdo_lock:
                data = packed[port.number]
                if port.last_data is None and not self.tpdo_on_start:  # OPERATIONAL, event-driven anew
                    port.last_data, port.last_sent = data, now
                changed = data != port.last_data and now - port.last_sent >= port.inhibit_s
                timer_due = port.event_timer_s > 0 and now - port.last_sent >= port.event_timer_s
                if changed or timer_due:
                    self.network.send_message(port.tpdo_cob_id, data)
                    port.last_data, port.last_sent = data, now
