"""One firmware axis as a CANopen (CiA 301) node: the CAN front end of the amplifier.

The node is the ``canopen`` package's :class:`canopen.LocalNode` (object
dictionary from the EDS in :mod:`feeder.protocol.eds`, NMT slave, heartbeat
producer, EMCY producer) with the amplifier behind its read/write hooks and
objects addressed by their EDS names.  It calls the same
:class:`firmware_sim.firmware.Axis` API as the ANC300 console: one amplifier,
two front ends.

Frames are handled when they arrive, in the thread that delivers them: on a
:class:`~firmware_sim.can_wire.CanWire` (``serve_slcan_pty``) that is the
adapter's pty thread, like a CAN receive interrupt; on any other python-can bus
the network's receive thread.  Each SDO request, NMT command, SYNC and RPDO is
handled whole under the firmware's lock, so it sees (and leaves) one consistent
state between two ticks, and every write goes through the axis' limits and
safety state machine.

What this module adds to ``LocalNode``:

- SDO writes outside the EDS's LowLimit/HighLimit abort with 0x06090031 (too
  high) / 0x06090032 (too low); values the firmware refuses abort with the same
  codes when the firmware's own limit is tighter (e.g. a lower amplitude rating),
  0x06040043 when they conflict with another setting (flyback longer than half
  a period), 0x08000022 when the axis' state forbids them (stepping while
  grounded or in fault).  A refused write changes nothing.  Unknown objects
  (0x06020000), sub-indices (0x06090011), read-only (0x06010002) and write-only
  (0x06010001) objects and client aborts follow CiA 301
  (:mod:`firmware_sim.sdo_server`).
- NMT: SDO served in PRE-OPERATIONAL and OPERATIONAL only; PDOs in OPERATIONAL
  only; any state but OPERATIONAL stops the axis; reset node / reset
  communication restore the EDS defaults (reset node also grounds the axis),
  send the boot-up message and enter PRE-OPERATIONAL.
- TPDO1 (step counter, status word, command acknowledge, error register):
  transmission type 254/255 sends on change (no faster than the inhibit time)
  and at least every event-timer period; type 1..240 sends on every n-th SYNC.
- RPDO1 (step command, command sequence): ``+N``/``-N`` starts a burst, 0 stops;
  the sequence is echoed in TPDO1's command acknowledge, with status bit 3 set
  when the firmware refused the command.  A too-short RPDO raises EMCY 0x8210.
- EMCY when a fault bit latches (code per fault, error register, fault word in
  bytes 3..6), and EMCY 0x0000 when the fault word is cleared.
- Heartbeat consumer (0x1016:1, producer id << 16 | ms): the host's heartbeats
  count as host activity; once one has arrived, none for the set time while
  the axis moves latches the firmware's ``host_watchdog`` fault (axis grounded,
  EMCY 0x8130).  Monitoring restarts with the next heartbeat.
"""

from __future__ import annotations

import re
import struct
import sys
import threading
import time
import zlib
from collections.abc import Callable
from typing import Any

import can
import canopen
from canopen.objectdictionary import ObjectDictionary, ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from feeder.errors import InputError
from feeder.protocol.eds import MODES, SHAPE_CODES, bit_mask, object_dictionary
from firmware_sim.can_wire import CanWire, WireBus
from firmware_sim.firmware import (
    FLYBACK_SHAPES,
    STEPPING_MODES,
    AxisStatus,
    Fault,
    Firmware,
    FirmwareError,
    LimitError,
)
from firmware_sim.sdo_server import SdoServer
from firmware_sim.slcan import SlcanPty

NMT_OPERATIONAL = 5
NMT_PRE_OPERATIONAL = 127
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82
NMT_ENTER_PRE_OPERATIONAL = 0x80
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

TIMED_SHAPES = ("linear", "half-cosine")
"""Flyback shapes that use ``Flyback time``; the others keep it only for later."""

LIMIT_FIELDS = {
    "Frequency": "frequency",
    "Amplitude": "voltage",
    "Flyback time": "flyback",
    "Offset": "offset",
    "Step command": "steps",
}
"""The firmware's name (``LimitError.field``) of the value each object sets."""

INTERRUPT_LATENCY_S = 100e-6
"""Longest wait of an arriving frame's thread for the interpreter (``sys.setswitchinterval``;
Python's default of 5 ms would let a busy tick delay an SDO answer by milliseconds)."""

IDLE_POLL_S = 0.01
"""How often a node without event-driven PDOs to send (not OPERATIONAL, or TPDO1 on
SYNC) samples its axis for EMCY and the heartbeat consumer."""

TPDO1 = "TPDO1 communication parameter"
CONSUMER_HEARTBEAT = "Consumer heartbeat time.Consumer heartbeat time 1"
LIVE_OBJECTS = (
    "Error register",
    "Frequency",
    "Amplitude",
    "Flyback shape",
    "Mode",
    "Offset",
    "Step counter",
    "Output voltage",
    "Fault word",
    "Status word",
    "Command acknowledge",
)
"""Objects whose value is the axis' (or the node's) present state, read when asked."""


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
    """Axis ``axis`` of ``firmware`` as CANopen node ``node_id`` on ``bus``.

    ``bus``: an endpoint of a :class:`~firmware_sim.can_wire.CanWire` (frames
    handled in the sender's thread) or any python-can bus (a receive thread).
    ``od``: the object dictionary (default: the packaged EDS).
    ``start()`` boots the node (boot-up message, PRE-OPERATIONAL, heartbeat);
    ``close()`` stops it and shuts the bus down.  ``poll_s`` is how often the
    node samples the axis for event-driven TPDO1 and EMCY.
    """

    def __init__(
        self,
        firmware: Firmware,
        axis: int,
        node_id: int,
        bus: can.BusABC,
        od: ObjectDictionary | None = None,
        poll_s: float = 0.001,
    ) -> None:
        self.firmware = firmware
        self.axis = firmware.axis(axis)
        self.node_id = node_id
        self.poll_s = poll_s
        self.local = canopen.LocalNode(node_id, od if od is not None else object_dictionary(node_id))
        self.local.sdo = SdoServer(self.local)
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = 0.1  # close() waits at most this long for the receiver
        self._tpdo_lock = threading.Lock()
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"canopen-node-{node_id}")
        self._ack = 0
        self._refused = False
        self._last_command = 0
        self._sync_count = 0
        self._fault_reported = 0
        self._flyback_ns = 0
        self._tpdo_type = 255
        self._inhibit_s = 0.0
        self._event_timer_s = 0.0
        self._consumer_id = 0  # host whose heartbeat is consumed; 0 = none
        self._consumer_timeout_s = 0.0
        self._consumer_seen: float | None = None
        self._writers: dict[str, Callable[[int], None]] = {
            "Frequency": lambda v: self.axis.set_frequency(v / 1000),
            "Amplitude": lambda v: self.axis.set_amplitude(v / 1000),
            "Flyback shape": self._write_flyback_shape,
            "Flyback time": self._write_flyback_time,
            "Mode": lambda v: self.axis.set_mode(MODES[v]),
            "Offset": lambda v: self.axis.set_offset(v / 1000),
            "Step command": self._write_step_command,
            "Continuous": self._write_continuous,
            "Fault reset": lambda v: self.axis.clear_faults(),
            f"{TPDO1}.Transmission type": self._write_tpdo_type,
            f"{TPDO1}.Inhibit time": lambda v: setattr(self, "_inhibit_s", v * 100e-6),
            f"{TPDO1}.Event timer": lambda v: setattr(self, "_event_timer_s", v / 1000),
            CONSUMER_HEARTBEAT: self._write_consumer_heartbeat,
        }
        od_ = self.local.object_dictionary
        for name in (*self._writers, *LIVE_OBJECTS, "Amplitude limit", "Identity object"):
            od_[name]  # a name the EDS lacks fails here, not on the first request
        self._status_mask = {
            name: bit_mask(od_, "Status word", name)
            for name in ("moving", "stepping mode", "fault", "refused")
        }

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
        tpdo = local.tpdo[1]
        self._tpdo_cob_id = tpdo.cob_id
        # TPDO1's layout from its mapping (byte-aligned, as in the EDS): packed with
        # struct, not through canopen's PDO variables, on every SYNC / change
        self._tpdo_layout = [(v.od.qualname, v.od.STRUCT_TYPES[v.od.data_type]) for v in tpdo.map]
        self._rpdo = local.rpdo[1]
        self._rpdo.add_callback(self._on_rpdo)
        bus = network.bus
        if isinstance(bus, WireBus):  # frames handled in the sender's thread, as they arrive
            bus.receiver = lambda m: network.notify(m.arbitration_id, m.data, m.timestamp)
        else:
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
        if reset_application:
            self.axis.ground()
            self._flyback_ns = 0
            self._last_command = 0
        self._tpdo_type = self._default(f"{TPDO1}.Transmission type")
        self._inhibit_s = self._default(f"{TPDO1}.Inhibit time") * 100e-6
        self._event_timer_s = self._default(f"{TPDO1}.Event timer") / 1000
        self._sync_count = 0
        self._consume_heartbeat(0, 0.0)
        self.local.nmt.send_command(0x81)  # state INITIALISING: boot-up message
        self.local.nmt.send_command(NMT_ENTER_PRE_OPERATIONAL)  # starts the heartbeat

    def _default(self, name: str) -> int:
        """An object's DefaultValue from the EDS."""
        variable = self.local.object_dictionary[name]
        assert isinstance(variable, ODVariable) and isinstance(variable.default, int)
        return variable.default

    # -- CAN services (each handled whole under the firmware's lock) -------------

    def _on_sdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.nmt_state in (NMT_PRE_OPERATIONAL, NMT_OPERATIONAL) and len(data) == 8:
            with self.firmware.lock:
                self.firmware.host_activity()
                self.local.sdo.on_request(can_id, data, timestamp)
            self._wake.set()

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id) or data[0] not in canopen.nmt.COMMAND_TO_STATE:
            return
        with self.firmware.lock:
            if canopen.nmt.COMMAND_TO_STATE[data[0]] != NMT_OPERATIONAL:
                self.axis.stop()  # before the heartbeat announces the new state
            self.local.nmt.on_command(can_id, data, timestamp)
            if data[0] in (NMT_RESET_NODE, NMT_RESET_COMMUNICATION):
                self._boot(reset_application=data[0] == NMT_RESET_NODE)
        self._wake.set()

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.nmt_state != NMT_OPERATIONAL or not 1 <= self._tpdo_type <= 240:
            return
        self._sync_count += 1
        if self._sync_count % self._tpdo_type == 0:
            self._send_tpdo(self.axis.status())

    def _on_rpdo(self, pdo: Any) -> None:
        if self.nmt_state != NMT_OPERATIONAL:
            return
        if len(pdo.data) * 8 < pdo.length:
            self.local.emcy.send(EMCY_PDO_LENGTH, error_register(self._fault_reported))
            return
        with self.firmware.lock:
            self.firmware.host_activity()
            count = int(pdo["Step command"].raw)
            try:
                self._write_step_command(count)
                self._refused = False
            except FirmwareError:
                self._refused = True
            self._ack = int(pdo["Command sequence"].raw)
        self._wake.set()

    # -- object dictionary hooks ------------------------------------------------

    def _on_read(self, index: int, subindex: int, od: ODVariable) -> int | None:
        name = od.qualname
        if name == "Identity object.Serial number":
            return serial_number_u32(self.firmware.config.serial_number)
        if name == "Amplitude limit":
            return round(self.firmware.config.amplifier.max_amplitude_vpp * 1000)
        if name == "Flyback time":
            status = self.axis.status()
            if status.flyback_shape in TIMED_SHAPES:  # set here or on the console
                return round(status.flyback_s * 1e9)
            return self._flyback_ns
        if name == "Step command":
            return self._last_command
        if name in LIVE_OBJECTS:
            return self._live_value(name, self.axis.status())
        return None

    def _live_value(self, name: str, status: AxisStatus) -> int:
        """Value of an object that mirrors the axis' (or the node's) present state."""
        if name == "Error register":
            return error_register(status.fault_word)
        if name == "Status word":
            bits = self._status_mask
            word = bits["moving"] if status.moving else 0
            word |= bits["stepping mode"] if status.mode in STEPPING_MODES else 0
            word |= bits["fault"] if status.fault_word else 0
            return word | (bits["refused"] if self._refused else 0)
        if name == "Command acknowledge":
            return self._ack
        return {
            "Frequency": lambda: round(status.frequency_hz * 1000),
            "Amplitude": lambda: round(status.amplitude_v * 1000),
            "Flyback shape": lambda: SHAPE_CODES.index(status.flyback_shape),
            "Mode": lambda: MODES.index(status.mode),
            "Offset": lambda: round(status.offset_v * 1000),
            "Step counter": lambda: status.step_counter,
            "Output voltage": lambda: round(status.output_v * 1000),
            "Fault word": lambda: status.fault_word,
        }[name]()

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        value = od.decode_raw(data)
        if not isinstance(value, int):
            return
        if od.min is not None and value < od.min:
            raise SdoAbortedError(ABORT_TOO_LOW)
        if od.max is not None and value > od.max:
            raise SdoAbortedError(ABORT_TOO_HIGH)
        writer = self._writers.get(od.qualname)
        if writer is None:
            return
        try:
            writer(value)
        except LimitError as exc:
            if exc.field != LIMIT_FIELDS.get(od.qualname):
                raise SdoAbortedError(ABORT_INCOMPATIBLE) from exc
            raise SdoAbortedError(ABORT_TOO_HIGH if exc.value > exc.hi else ABORT_TOO_LOW) from exc
        except FirmwareError as exc:
            raise SdoAbortedError(ABORT_DEVICE_STATE) from exc

    def _write_tpdo_type(self, value: int) -> None:
        if 240 < value < 254:
            raise SdoAbortedError(ABORT_RANGE)
        self._tpdo_type = value
        self._sync_count = 0

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

    def _write_flyback_shape(self, code: int) -> None:
        self.axis.set_flyback(FLYBACK_SHAPES[code], self._flyback_ns / 1e9)

    def _write_flyback_time(self, ns: int) -> None:
        shape = self.axis.status().flyback_shape
        if shape in TIMED_SHAPES:
            self.axis.set_flyback(shape, ns / 1e9)
        self._flyback_ns = ns

    def _write_step_command(self, count: int) -> None:
        if count == 0:
            self.axis.stop()
        else:
            self.axis.step(count)
        self._last_command = count

    def _write_continuous(self, direction: int) -> None:
        if direction == 0:
            self.axis.stop()
        else:
            self.axis.run_continuous(up=direction > 0)

    # -- TPDO1 and EMCY ---------------------------------------------------------

    def _pack_tpdo(self, status: AxisStatus) -> bytes:
        """TPDO1's data for ``status``, per its mapping."""
        return b"".join(layout.pack(self._live_value(name, status)) for name, layout in self._tpdo_layout)

    def _send_tpdo(self, status: AxisStatus) -> None:
        with self._tpdo_lock:
            self.network.send_message(self._tpdo_cob_id, self._pack_tpdo(status))

    def _report_faults(self, fault_word: int) -> None:
        new = fault_word & ~self._fault_reported
        register = error_register(fault_word)
        detail = struct.pack("<IB", fault_word, 0)
        for bit in Fault:
            if new & bit:
                self.local.emcy.send(EMCY_CODES.get(bit, 0x1000), register, detail)
        if self._fault_reported and not fault_word:
            self.local.emcy.reset(0, detail)
        self._fault_reported = fault_word

    def _run(self) -> None:
        """Sample the axis every ``poll_s`` (every :data:`IDLE_POLL_S` while no PDOs
        flow): EMCY on fault changes, TPDO1 when due."""
        last_data: bytes | None = None
        last_sent = 0.0
        while not self._stopping.is_set():
            pdos_flow = self.nmt_state == NMT_OPERATIONAL and self._tpdo_type >= 254
            self._wake.wait(self.poll_s if pdos_flow else max(self.poll_s, IDLE_POLL_S))
            self._wake.clear()
            status = self.axis.status()
            seen = self._consumer_seen
            if seen is not None and time.monotonic() - seen > self._consumer_timeout_s:
                self._consumer_seen = None  # one event per silence
                if status.moving:
                    self.axis.inject_fault(Fault.HOST_WATCHDOG)
                    status = self.axis.status()
            state = self.nmt_state
            if state in (NMT_PRE_OPERATIONAL, NMT_OPERATIONAL) and status.fault_word != self._fault_reported:
                self._report_faults(status.fault_word)
            if state != NMT_OPERATIONAL or self._tpdo_type < 254:
                last_data = None
                continue
            now = time.monotonic()
            with self._tpdo_lock:
                data = self._pack_tpdo(status)
                changed = data != last_data and now - last_sent >= self._inhibit_s
                timer_due = self._event_timer_s > 0 and now - last_sent >= self._event_timer_s
                if changed or timer_due:
                    self.network.send_message(self._tpdo_cob_id, data)
                    last_data, last_sent = data, now


def serve_slcan_pty(firmware: Firmware, node_id_base: int = 1) -> tuple[str, Callable[[], None]]:
    """Every configured axis as a node (id = ``node_id_base`` + axis − 1) behind an
    emulated SLCAN adapter on one :class:`CanWire`; returns the pty path and a
    function that stops it all.

    Sets the interpreter's switch interval to :data:`INTERRUPT_LATENCY_S`: the
    thread a frame arrives in then gets the interpreter from the busy tick
    thread within that time, as an interrupt preempts a firmware's main loop.
    """
    if not 1 <= node_id_base <= 128 - max(firmware.axis_numbers):
        raise InputError(
            "--can-node-id-base",
            f"node ids {node_id_base}..{node_id_base + max(firmware.axis_numbers) - 1}"
            " leave CANopen's 1..127",
        )
    sys.setswitchinterval(INTERRUPT_LATENCY_S)
    wire = CanWire()
    adapter = SlcanPty(wire.bus()).start()
    nodes = [
        CanopenNode(firmware, axis, node_id_base + axis - 1, wire.bus()).start()
        for axis in firmware.axis_numbers
    ]

    def close() -> None:
        for node in nodes:
            node.close()
        adapter.close()

    return adapter.path, close
