"""One firmware axis' objects on a CANopen node: what :class:`AxisPort` reads and writes.

A node (:class:`firmware_sim.canopen_node.CanopenNode`) has one port per axis its
EDS lists: the one-axis EDS has one, named by the plain object names; the
three-axis EDS has three, whose objects are named ``"Axis n <name>"`` and whose
PDOs are RPDOn/TPDOn (:func:`feeder.protocol.eds.axis_object`).  The port maps its
objects to the :class:`firmware_sim.axis.Axis` API, holds the axis' PDO state
(RPDO acknowledge, TPDO transmission parameters) and packs its TPDO.  The node
calls it with the firmware's lock held.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from canopen.objectdictionary import ObjectDictionary, ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from feeder.protocol.eds import MODES, SHAPE_CODES, axis_object, bit_mask
from firmware_sim.axis import FLYBACK_SHAPES, STEPPING_MODES, Axis, AxisStatus

ABORT_RANGE = 0x06090030

TIMED_SHAPES = ("linear", "half-cosine")
"""Flyback shapes that use ``Flyback time``; the others keep it only for later."""

LIVE_OBJECTS = (
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
"""An axis' objects whose value is the axis' present state, read when asked."""

MOTION_OBJECTS = ("Step command", "Continuous")
"""An axis' objects whose non-zero value starts motion (the node refuses that by SDO
outside OPERATIONAL); 0 stops, in any state."""

NODE_REGISTER = "Error register"
"""The node's object every TPDO carries besides the axis' own."""


def int32(value: int) -> int:
    """``value`` wrapped to a 32-bit two's-complement integer, as a drive's I32 counter runs:
    ``2**31 - 1`` + 1 step is ``-2**31``; a host takes differences modulo ``2**32``."""
    return (value + (1 << 31)) % (1 << 32) - (1 << 31)


class AxisPort:
    """Axis ``number`` (1-based) of a node whose dictionary is ``od``, backed by firmware ``axis``."""

    def __init__(self, od: ObjectDictionary, axis: Axis, number: int) -> None:
        self.axis = axis
        self.number = number
        self.od = od
        self.tpdo_record = f"TPDO{number} communication parameter"
        self.ack = 0
        self.refused = False
        self.last_command = 0
        self.flyback_ns = 0
        self.tpdo_type = 255
        self.inhibit_s = 0.0
        self.event_timer_s = 0.0
        self.sync_count = 0
        self.fault_reported = 0
        self.last_data: bytes | None = None
        self.last_sent = 0.0
        self.tpdo_cob_id = 0
        self.tpdo_layout: list[tuple[str, struct.Struct]] = []
        writers: dict[str, Callable[[int], None]] = {
            "Frequency": lambda v: axis.set_frequency(v / 1000),
            "Amplitude": lambda v: axis.set_amplitude(v / 1000),
            "Flyback shape": self._write_flyback_shape,
            "Flyback time": self._write_flyback_time,
            "Mode": lambda v: axis.set_mode(MODES[v]),
            "Offset": lambda v: axis.set_offset(v / 1000),
            "Step command": self.write_step_command,
            "Continuous": self._write_continuous,
            "Fault reset": lambda v: axis.clear_faults(),
        }
        self.writers = {self.name(name): writer for name, writer in writers.items()}
        self.writers.update(
            {
                f"{self.tpdo_record}.Transmission type": self._write_tpdo_type,
                f"{self.tpdo_record}.Inhibit time": lambda v: setattr(self, "inhibit_s", v * 100e-6),
                f"{self.tpdo_record}.Event timer": lambda v: setattr(self, "event_timer_s", v / 1000),
            }
        )
        self.step_command = self.name("Step command")
        self.command_sequence = self.name("Command sequence")
        self.base = {self.name(name): name for name in (*writers, *LIVE_OBJECTS, "Amplitude limit")}
        """This axis' object names → their one-axis names."""
        for name in (*self.writers, *self.base):
            od[name]  # a name the EDS lacks fails here, not on the first request
        self.status_mask = {
            bit: bit_mask(od, self.name("Status word"), bit)
            for bit in ("moving", "stepping mode", "fault", "refused")
        }

    def name(self, name: str) -> str:
        """The EDS name of this axis' object ``name``."""
        return axis_object(self.od, self.number, name)

    def default(self, name: str) -> int:
        """An object's DefaultValue from the EDS."""
        variable = self.od[name]
        assert isinstance(variable, ODVariable) and isinstance(variable.default, int)
        return variable.default

    def reset(self, reset_application: bool) -> None:
        """Back to the EDS defaults (communication objects; all objects on reset node)."""
        if reset_application:
            self.axis.ground()
            self.flyback_ns = 0
            self.last_command = 0
        self.tpdo_type = self.default(f"{self.tpdo_record}.Transmission type")
        self.inhibit_s = self.default(f"{self.tpdo_record}.Inhibit time") * 100e-6
        self.event_timer_s = self.default(f"{self.tpdo_record}.Event timer") / 1000
        self.sync_count = 0

    # -- reads ------------------------------------------------------------------

    def read(self, base: str, register: Callable[[], int]) -> int | None:
        """The value of this axis' object ``base`` (its one-axis name) now; None: the stored one."""
        if base == "Flyback time":
            status = self.axis.status()
            if status.flyback_shape in TIMED_SHAPES:  # set here or on the console
                return round(status.flyback_s * 1e9)
            return self.flyback_ns
        if base == "Step command":
            return self.last_command
        if base in LIVE_OBJECTS:
            return self.live_value(base, self.axis.status(), register)
        return None

    def live_value(self, base: str, status: AxisStatus, register: Callable[[], int]) -> int:
        """Value of an object that mirrors the axis' (or, for the error register, the node's) state."""
        if base == NODE_REGISTER:
            return register()
        if base == "Status word":
            bits = self.status_mask
            word = bits["moving"] if status.moving else 0
            word |= bits["stepping mode"] if status.mode in STEPPING_MODES else 0
            word |= bits["fault"] if status.fault_word else 0
            return word | (bits["refused"] if self.refused else 0)
        if base == "Command acknowledge":
            return self.ack
        return {
            "Frequency": lambda: round(status.frequency_hz * 1000),
            "Amplitude": lambda: round(status.amplitude_v * 1000),
            "Flyback shape": lambda: SHAPE_CODES.index(status.flyback_shape),
            "Mode": lambda: MODES.index(status.mode),
            "Offset": lambda: round(status.offset_v * 1000),
            "Step counter": lambda: int32(status.step_counter),  # the object is I32 (SDO and TPDO)
            "Output voltage": lambda: round(status.output_v * 1000),
            "Fault word": lambda: status.fault_word,
        }[base]()

    def pack_tpdo(self, status: AxisStatus, register: int) -> bytes:
        """The axis' TPDO data for ``status`` (and the node's error register), per its mapping."""
        return b"".join(
            layout.pack(self.live_value(self.base.get(name, name), status, lambda: register))
            for name, layout in self.tpdo_layout
        )

    # -- writes -----------------------------------------------------------------

    def _write_tpdo_type(self, value: int) -> None:
        if 240 < value < 254:
            raise SdoAbortedError(ABORT_RANGE)
        self.tpdo_type = value
        self.sync_count = 0

    def _write_flyback_shape(self, code: int) -> None:
        self.axis.set_flyback(FLYBACK_SHAPES[code], self.flyback_ns / 1e9)

    def _write_flyback_time(self, ns: int) -> None:
        shape = self.axis.status().flyback_shape
        if shape in TIMED_SHAPES:
            self.axis.set_flyback(shape, ns / 1e9)
        self.flyback_ns = ns

    def write_step_command(self, count: int) -> None:
        if count == 0:
            self.axis.stop()
        else:
            self.axis.step(count)
        self.last_command = count

    def _write_continuous(self, direction: int) -> None:
        if direction == 0:
            self.axis.stop()
        else:
            self.axis.run_continuous(up=direction > 0)
