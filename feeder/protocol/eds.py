"""The amplifier's CANopen contract: its EDS (package data) and the codes of its objects.

Two EDS (CiA 306) ship in this package, read with :mod:`importlib.resources` so an
installed package finds them wherever it lives:

- ``feeder_amplifier.eds`` (:data:`EDS_FILE`, the default): one axis per node;
- ``feeder_amplifier_3axis.eds`` (:data:`EDS_3AXIS_FILE`): three axes per node, laid
  out as a CiA 301 *multiple device module*: Device type (0x1000) has the additional
  information FFFFh, logical device n (axis n) has its Device type at
  0x67FF + 0x800·(n − 1), and axis n's objects are the one-axis objects moved by
  0x800·(n − 1) (the per-axis stride of CiA 402 multi-axis drives) and named
  ``"Axis n <name>"``; axis n uses RPDOn and TPDOn.

The EDS alone says how many axes a node has (:func:`axis_count`);
:func:`axis_object` names an axis' object in either layout.  :func:`object_dictionary`
returns a dictionary with the code tables below attached (value descriptions and bit
definitions), so both the host's driver and ``firmware_sim``'s node address objects
by their EDS ``ParameterName`` and values by name (``sdo["Mode"].desc = "stp"``).
Reference: docs/canopen.md.
"""

from __future__ import annotations

import configparser
import io
from importlib import resources
from pathlib import Path

from canopen.objectdictionary import ObjectDictionary, ODVariable
from canopen.objectdictionary.eds import import_eds

from feeder.errors import InputError
from feeder.protocol.anc300 import FAULT_BITS, MODES
from feeder.waveform import FLYBACK_SHAPES

EDS_FILE = "feeder_amplifier.eds"
"""The packaged one-axis-per-node EDS (the default)."""
EDS_3AXIS_FILE = "feeder_amplifier_3axis.eds"
"""The packaged three-axes-per-node EDS."""
PACKAGED_EDS = (EDS_FILE, EDS_3AXIS_FILE)

AXIS_STRIDE = 0x800
"""Index distance between two axes' objects (CiA 301 logical devices, CiA 402 axes)."""
MULTIPLE_DEVICE_MODULE = 0xFFFF
"""Device type (0x1000) bits 16..31 of a multiple device module (CiA 301)."""
LOGICAL_DEVICE_TYPE = 0x67FF
"""Device type of logical device 1; logical device n's is at + 0x800·(n − 1) (CiA 301)."""
MAX_AXES = 8
"""CiA 301 allows 8 logical devices per node."""

SHAPE_CODES = (*FLYBACK_SHAPES, "custom")
"""``Flyback shape`` (0x2002): value = index; ``custom`` (user tables) is read-only."""

STATUS_WORD_BITS = ("moving", "stepping mode", "fault", "refused")
"""``Status word`` (0x2015), bit 0 first; ``refused``: the last RPDO command was refused."""

VALUE_NAMES = {"Mode": MODES, "Flyback shape": SHAPE_CODES}
"""Value descriptions: ``Mode`` (0x2005) value = index in the ANC300's mode names."""
BIT_NAMES = {
    "Status word": {name: bit for bit, name in enumerate(STATUS_WORD_BITS)},
    "Fault word": {name: mask.bit_length() - 1 for name, mask in FAULT_BITS.items()},
}
"""Bit definitions: ``Fault word`` (0x2014) holds the firmware's fault bits."""


def eds_text(eds: str, field: str = "eds") -> str:
    """The text of ``eds``: a packaged EDS's file name (:data:`PACKAGED_EDS`) or a path;
    :class:`InputError` naming ``field`` when there is none."""
    try:
        if eds in PACKAGED_EDS:
            return resources.files(__package__).joinpath(eds).read_text(encoding="ascii")
        return Path(eds).read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError) as exc:
        known = ", ".join(PACKAGED_EDS)
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise InputError(field, f"no EDS {eds!r} ({reason}; packaged: {known})") from None


def object_dictionary(node_id: int, eds: str = EDS_FILE, field: str = "eds") -> ObjectDictionary:
    """The object dictionary of node ``node_id`` (``$NODEID`` resolved) from ``eds`` (a
    packaged EDS's name or a path), code tables attached to every axis' objects;
    :class:`InputError` naming ``field`` for an EDS that is missing or not this amplifier's."""
    text = eds_text(eds, field)
    try:
        od = import_eds(io.StringIO(text), node_id)
    except (configparser.Error, ValueError, KeyError, TypeError) as exc:  # canopen's, on a malformed file
        first_line = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise InputError(field, f"{eds!r} is not a readable EDS ({first_line})") from None
    try:
        for axis in range(1, axis_count(od) + 1):
            for name, values in VALUE_NAMES.items():
                variable = entry(od, axis_object(od, axis, name))
                for code, value in enumerate(values):
                    variable.add_value_description(code, value)
            for name, bits in BIT_NAMES.items():
                variable = entry(od, axis_object(od, axis, name))
                for bit_name, bit in bits.items():
                    variable.add_bit_definition(bit_name, [bit])
    except KeyError as exc:
        raise InputError(field, f"{eds!r} lacks the amplifier's object {exc}") from None
    return od


def axis_count(od: ObjectDictionary) -> int:
    """How many axes the node has: 1, or for a multiple device module (0x1000 bits 16..31 =
    FFFFh) the logical devices whose Device type (0x67FF + 0x800·k) the EDS lists."""
    device_type = od.get_variable(0x1000)
    default = device_type.default if device_type is not None else 0
    if not isinstance(default, int) or default >> 16 != MULTIPLE_DEVICE_MODULE:
        return 1
    count = 0
    while count < MAX_AXES and LOGICAL_DEVICE_TYPE + AXIS_STRIDE * count in od:
        count += 1
    return max(count, 1)


def axis_object(od: ObjectDictionary, axis: int, name: str) -> str:
    """The ``ParameterName`` of axis ``axis``'s object ``name`` (its one-axis name):
    ``name`` itself on a one-axis node, ``"Axis n name"`` on a multi-axis one."""
    return name if axis_count(od) == 1 else f"Axis {axis} {name}"


def entry(od: ObjectDictionary, name: str) -> ODVariable:
    """The variable called ``name`` (a top-level ``ParameterName``); KeyError if absent."""
    variable = od[name]
    if not isinstance(variable, ODVariable):
        raise KeyError(f"{name!r} is a record or array, not a variable")
    return variable


def bit_mask(od: ObjectDictionary, name: str, bit_name: str) -> int:
    """The mask of bit ``bit_name`` of variable ``name``."""
    return sum(1 << bit for bit in entry(od, name).bit_definitions[bit_name])
