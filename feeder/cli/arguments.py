"""Argument types and option groups shared by the sub-commands.

Light to import (``feeder --help`` and ``feeder status`` load it): the physics
modules are imported inside the functions that need them.
"""

from __future__ import annotations

import argparse
import math
import re
from dataclasses import replace
from decimal import Decimal, DecimalException
from pathlib import Path
from typing import TYPE_CHECKING

from feeder.errors import InputError
from feeder.parts import SILICON_DENSITY_KG_M3, Part, Support

if TYPE_CHECKING:
    from feeder.surface.parameters import SurfaceParameters

#: length units of :func:`parse_length`: unit → power of ten of a metre (no unit: metres)
LENGTH_UNITS: dict[str, int] = {"m": 0, "mm": -3, "um": -6, "µm": -6, "μm": -6, "nm": -9}
_UNIT = "|".join(LENGTH_UNITS)
_DIGITS = r"(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_LENGTH = re.compile(rf"\s*([-+]?{_DIGITS})\s*({_UNIT})?\s*")
#: a negative number with an optional length unit: argparse takes it as a value, not an option
NEGATIVE_LENGTH = re.compile(rf"^-{_DIGITS}\s*(?:{_UNIT})?$")


def parse_length(text: str) -> float:
    """A length in metres from ``150um``, ``150µm``, ``1.2mm``, ``-20 nm`` or ``3e-4`` (metres).

    Scaled in decimal, so ``150um`` is exactly the float ``150e-6``.  Raises
    :class:`ValueError` naming the accepted units.
    """
    match = _LENGTH.fullmatch(text)
    if match is None:
        raise ValueError(f"expected a length such as 150um, 1.2mm or 3e-4 (metres; units "
                         f"{', '.join(LENGTH_UNITS)}), got {text!r}")
    try:
        value = float(Decimal(match.group(1)).scaleb(LENGTH_UNITS[match.group(2) or "m"]))
    except DecimalException:        # exponent beyond decimal's range
        value = math.inf
    if not math.isfinite(value):
        raise ValueError(f"expected a finite length, got {text!r}")
    return value


def length(text: str) -> float:
    """argparse type: a length in metres, with an optional unit (:func:`parse_length`)."""
    try:
        return parse_length(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def allow_negative_lengths(parser: argparse.ArgumentParser) -> None:
    """Let ``-100um`` and ``-1e-4`` be values (``--by -20um``, ``move -100um``), not options.

    argparse itself only knows ``-1`` and ``-.5``; the parser must have no option that looks
    like a negative number.
    """
    parser._negative_number_matcher = NEGATIVE_LENGTH


def positive_float(text: str) -> float:
    """argparse type: a positive finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def add_part_arguments(
    p: argparse.ArgumentParser, *, part_required: bool = True, example: str = "300x300x50"
) -> None:
    """``--part``, ``--support``, ``--surface`` and ``--density``."""
    p.add_argument("--part", required=part_required, help=f"LxWxT in µm, e.g. {example}")
    p.add_argument("--support", default="flat", help="flat or grooved (default flat)")
    p.add_argument("--surface", type=Path, help="surface TOML (default: the embedded surface)")
    p.add_argument("--density", type=positive_float, default=SILICON_DENSITY_KG_M3,
                   help=f"part density in kg/m³ (default silicon, {SILICON_DENSITY_KG_M3:g})")
    p.add_argument("--adhesion-work", type=float, metavar="J_M2",
                   help="work of adhesion w in J/m² for DMT adhesion per summit (default: the "
                        "surface file's, else 0 as in the paper; silicon in air ≈ 0.1)")


def add_tau_arguments(p: argparse.ArgumentParser, *, band: bool = True) -> None:
    """``--tau`` (and ``--tau-band``)."""
    from feeder.contact.breakaway import DEFAULT_TAU_BAND_PA, DEFAULT_TAU_PA

    p.add_argument("--tau", type=positive_float, default=DEFAULT_TAU_PA,
                   help=f"interfacial shear strength in Pa (default {DEFAULT_TAU_PA:g})")
    if band:
        p.add_argument("--tau-band", type=float, default=DEFAULT_TAU_BAND_PA,
                       help=f"± uncertainty of τ in Pa (default {DEFAULT_TAU_BAND_PA:g})")


def surface_from(args: argparse.Namespace) -> SurfaceParameters:
    """The ``--surface`` file (or the embedded default), with ``--adhesion-work`` applied."""
    from feeder.surface.parameters import DEFAULT_SURFACE, load_surface

    surface = load_surface(args.surface) if args.surface else DEFAULT_SURFACE
    if getattr(args, "adhesion_work", None) is None:
        return surface
    try:
        return replace(surface, adhesion_work_j_m2=args.adhesion_work)
    except InputError as err:
        raise InputError("--adhesion-work", err.message) from None


def part_from(args: argparse.Namespace) -> tuple[Part, Support, SurfaceParameters]:
    """Part, support and surface from :func:`add_part_arguments`' options."""
    return Part.parse(args.part, density_kg_m3=args.density), Support.parse(args.support), surface_from(args)
