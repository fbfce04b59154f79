"""The amplifier's CANopen contract: its EDS (package data) and the codes of its objects.

The EDS (CiA 306, ``feeder_amplifier.eds`` in this package) is read with
:mod:`importlib.resources`, so an installed package finds it wherever it lives.
:func:`object_dictionary` returns it with the code tables below attached
(value descriptions and bit definitions), so both the host's driver and
``firmware_sim``'s node address objects by their EDS ``ParameterName`` and
values by name (``sdo["Mode"].desc = "stp"``).  Reference: docs/canopen.md.
"""

from __future__ import annotations

from importlib import resources
from typing import TextIO, cast

import canopen
from canopen.objectdictionary import ObjectDictionary, ODVariable

from feeder.protocol.anc300 import FAULT_BITS, MODES
from feeder.waveform import FLYBACK_SHAPES

EDS_FILE = "feeder_amplifier.eds"

SHAPE_CODES = (*FLYBACK_SHAPES, "custom")
"""``Flyback shape`` (0x2002): value = index; ``custom`` (user tables) is read-only."""

STATUS_WORD_BITS = ("moving", "stepping mode", "fault", "refused")
"""``Status word`` (0x2015), bit 0 first; ``refused``: the last RPDO1 command was refused."""

VALUE_NAMES = {"Mode": MODES, "Flyback shape": SHAPE_CODES}
"""Value descriptions: ``Mode`` (0x2005) value = index in the ANC300's mode names."""
BIT_NAMES = {
    "Status word": {name: bit for bit, name in enumerate(STATUS_WORD_BITS)},
    "Fault word": {name: mask.bit_length() - 1 for name, mask in FAULT_BITS.items()},
}
"""Bit definitions: ``Fault word`` (0x2014) holds the firmware's fault bits."""


def object_dictionary(node_id: int) -> ObjectDictionary:
    """The object dictionary of node ``node_id`` (``$NODEID`` resolved), code tables attached."""
    with resources.files(__package__).joinpath(EDS_FILE).open("r", encoding="ascii") as eds:
        od = canopen.import_od(cast(TextIO, eds), node_id)
    for name, values in VALUE_NAMES.items():
        variable = entry(od, name)
        for code, value in enumerate(values):
            variable.add_value_description(code, value)
    for name, bits in BIT_NAMES.items():
        variable = entry(od, name)
        for bit_name, bit in bits.items():
            variable.add_bit_definition(bit_name, [bit])
    return od


def entry(od: ObjectDictionary, name: str) -> ODVariable:
    """The variable called ``name`` (a top-level ``ParameterName``); KeyError if absent."""
    variable = od[name]
    if not isinstance(variable, ODVariable):
        raise KeyError(f"{name!r} is a record or array, not a variable")
    return variable


def bit_mask(od: ObjectDictionary, name: str, bit_name: str) -> int:
    """The mask of bit ``bit_name`` of variable ``name``."""
    return sum(1 << bit for bit in entry(od, name).bit_definitions[bit_name])
