"""Argument types and option groups shared by the sub-commands.

Light to import (``feeder --help`` and ``feeder status`` load it): the physics
modules are imported inside the functions that need them.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from decimal import Decimal, DecimalException
from pathlib import Path
from typing import TYPE_CHECKING, Any

from feeder.errors import InputError, shown
from feeder.parts import (
    DENSITY_RANGE_KG_M3,
    PART_SIDE_RANGE_UM,
    PART_THICKNESS_RANGE_UM,
    SILICON_DENSITY_KG_M3,
    Part,
    Support,
)
from feeder.surface.parameters import ADHESION_WORK_HELP, ADHESION_WORK_RANGE_J_M2, adhesion_work_problem

if TYPE_CHECKING:
    from feeder.materials import Material
    from feeder.surface.parameters import SurfaceParameters


def positive_float(text: str) -> float:
    """argparse type: a positive finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def float_in(low: float, high: float) -> Callable[[str], float]:
    """argparse type: a finite number in [``low``, ``high``]."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text[:40]!r}") from None
        if not low <= value <= high:  # NaN fails too
            raise argparse.ArgumentTypeError(f"must be from {low:g} to {high:g}, got {text[:40]!r}")
        return value

    return parse


def adhesion_work(text: str) -> float:
    """argparse type: a work of adhesion in J/m², 0 or 1 µJ/m²–10 J/m² (``ADHESION_WORK_RANGE_J_M2``)."""
    value = float_in(0.0, ADHESION_WORK_RANGE_J_M2[1])(text)
    if adhesion_work_problem(value) is not None:
        raise argparse.ArgumentTypeError(f"must be {ADHESION_WORK_HELP} J/m², got {text[:40]!r}")
    return value


def int_in(low: int, high: int) -> Callable[[str], int]:
    """argparse type: an integer in [``low``, ``high``] (a 400-digit number is refused, not parsed)."""

    def parse(text: str) -> int:
        digits = text.strip().lstrip("+-")
        if not digits.isascii() or not digits.isdigit() or len(digits) > 30:
            raise argparse.ArgumentTypeError(f"expected an integer from {low} to {high}, got {text[:40]!r}")
        value = int(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be from {low} to {high}, got {value}")
        return value

    return parse


def add_sim_arg(parser: argparse.ArgumentParser, example: str) -> None:
    """``--sim-arg ARG`` (repeatable): an extra firmware_sim argument for an embedded simulator."""
    parser.add_argument(
        "--sim-arg",
        action="append",
        default=[],
        metavar="ARG",
        help=f"extra firmware_sim argument when no hardware is named (repeatable; e.g. {example})",
    )


def output_path(text: str) -> Path:
    """argparse type: a file to write: a name, in a directory that exists, not a directory itself."""
    path = Path(text)
    if not text or not path.name:
        raise argparse.ArgumentTypeError(f"expected a file name, got {text!r}")
    if len(path.name.encode()) > 200:
        raise argparse.ArgumentTypeError(f"file name longer than 200 bytes: {text[:40]!r}...")
    if not path.parent.is_dir():
        raise argparse.ArgumentTypeError(f"no such directory: {str(path.parent)!r}")
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"is a directory: {text!r}")
    if path.exists() and not path.is_file():
        raise argparse.ArgumentTypeError(f"exists and is not a regular file: {text!r}")
    return path


def refuse_overwriting_inputs(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """:class:`InputError` naming the option when a file to write (an :func:`output_path`) is
    one the command reads, or another output of the same command (``waveform export F.toml
    --out F.toml`` replaced the design file with its CSV)."""
    actions: list[argparse.Action] = []
    current: argparse.ArgumentParser | None = parser
    while current is not None:  # the chosen (sub-)sub-command's options
        subs = [a for a in current._actions if isinstance(a, argparse._SubParsersAction)]
        actions += [a for a in current._actions if a not in subs]
        chosen = getattr(args, subs[0].dest, None) if subs else None
        current = subs[0].choices.get(chosen) if subs and isinstance(chosen, str) else None
    outputs: list[tuple[str, Path]] = []
    inputs: list[Path] = []
    for action in actions:
        values = _flat(getattr(args, action.dest, None))
        if action.type is output_path:
            name = action.option_strings[0] if action.option_strings else action.dest
            outputs += [(name, v) for v in values if isinstance(v, Path)]
        else:  # a file named in plain text too: `calibrate --x-move D BEFORE AFTER`, `grab VIDEO`
            inputs += [Path(v) for v in values if isinstance(v, (Path, str)) and _names_a_file(v)]
    for i, (option, out) in enumerate(outputs):
        target = out.resolve()
        if any(target == p.resolve() for p in inputs):
            raise InputError(option, f"{out} is also read by this command: it would be overwritten")
        if any(target == other.resolve() for _, other in outputs[:i]):
            raise InputError(option, f"{out} is also another output of this command")


def _flat(value: object) -> list[object]:
    """An option's value as a flat list (``nargs`` with ``append`` gives lists of lists)."""
    if isinstance(value, list):
        return [item for each in value for item in _flat(each)]
    return [value]


def _names_a_file(value: str | Path) -> bool:
    """``value`` is the path of a regular file (not when no path could be so named: too long,
    a NUL byte)."""
    try:
        return Path(value).is_file()
    except (OSError, ValueError):
        return False


def input_path(text: str) -> Path:
    """argparse type: a file to read: a regular file that exists (not a device such as /dev/zero)."""
    path = Path(text)
    try:
        if not path.is_file():
            raise argparse.ArgumentTypeError(
                f"no such file: {shown(text)}" if not path.exists() else f"not a regular file: {shown(text)}"
            )
    except OSError as err:  # e.g. a name too long
        raise argparse.ArgumentTypeError(f"cannot read {shown(text)}: {err.strerror}") from None
    return path


_LENGTH_UNITS_M = {"": 1.0, "m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "μm": 1e-6, "nm": 1e-9}
_PRESSURE_UNITS_PA = {"": 1.0, "Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "GPa": 1e9}
_ANGLE_UNITS_RAD = {"": 1.0, "rad": 1.0, "deg": math.pi / 180, "°": math.pi / 180}
_QUANTITY_RE = re.compile(r"^\s*([-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?)\s*([^\d\s.+-]*)\s*$")


def _quantity(text: str, units: dict[str, float], what: str, example: str) -> float:
    match = _QUANTITY_RE.match(text)
    if match is None or match.group(2) not in units:
        raise argparse.ArgumentTypeError(
            f"expected {'an' if what[0] in 'aeiou' else 'a'} {what} like {example} "
            f"(units: {', '.join(u for u in units if u)}), got {text!r}"
        )
    try:  # in decimal, so 150um is exactly the float 150e-6
        value = float(Decimal(match.group(1)) * Decimal(repr(units[match.group(2)])))
    except DecimalException:  # an exponent beyond decimal's range
        value = math.inf
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"not a finite {what}: {text!r}")
    return value


def length_m(text: str) -> float:
    """argparse type: a length with a unit (``150um``, ``1µm``, ``1.2mm``) or in metres (``1e-6``) → m."""
    return _quantity(text, _LENGTH_UNITS_M, "length", "1.5um")


def _positive(parse: Callable[[str], float], what: str) -> Callable[[str], float]:
    """argparse type: ``parse``'s value, refused unless positive (``what``: how it is named)."""

    def positive(text: str) -> float:
        value = parse(text)
        if value <= 0:
            raise argparse.ArgumentTypeError(f"must be a positive {what}, got {text!r}")
        return value

    return positive


positive_length_m = _positive(length_m, "length")
"""argparse type: a positive length (see :func:`length_m`) → m."""


def length_in(low_m: float, high_m: float) -> Callable[[str], float]:
    """argparse type: a length (see :func:`length_m`) in [``low_m``, ``high_m``] → m."""

    def parse(text: str) -> float:
        value = length_m(text)
        if not low_m <= value <= high_m:
            raise argparse.ArgumentTypeError(f"must be from {low_m:g} m to {high_m:g} m, got {text[:40]!r}")
        return value

    return parse


def pressure_pa(text: str) -> float:
    """argparse type: a pressure or stress with a unit (``22GPa``, ``300kPa``) or in pascals → Pa."""
    return _quantity(text, _PRESSURE_UNITS_PA, "pressure", "22GPa")


positive_pressure_pa = _positive(pressure_pa, "number of pascals (or 22GPa)")
"""argparse type: a positive pressure (see :func:`pressure_pa`) → Pa."""


MIN_SOLID_TAU_PA = 1e3
"""A shear strength below 1 kPa is no solid contact's (the paper's τ is 22.18 GPa; with adhesion
fitted, GPa too): a given ``--tau`` below it is almost certainly in the wrong unit."""


class _ShearStrengthAction(argparse.Action):
    """Store ``--tau``; below :data:`MIN_SOLID_TAU_PA` the command, once it has run, prints a warning
    on stderr, or its bad-input error (one line, exit 2) says it at its end."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[Any] | None,
        option_string: str | None = None,
    ) -> None:
        setattr(namespace, self.dest, values)
        handler = getattr(namespace, "handler", None)
        if handler is None or getattr(handler, "warns_of_low_tau", False):
            return
        prog, dest = parser.prog, self.dest

        def run(args: argparse.Namespace) -> int:
            tau = getattr(args, dest, None)
            if tau is None or tau >= MIN_SOLID_TAU_PA:
                return int(handler(args))
            slip = f"--tau {tau:g} Pa is below {MIN_SOLID_TAU_PA:g} Pa, no solid contact's shear strength"
            try:
                code = int(handler(args))
            except InputError as err:  # the error stays one line: the hint goes at its end
                raise InputError(err.field, f"{err.message} (note: {slip}: a unit slip?)") from None
            print(f"{prog}: warning: {slip} (the paper's τ is 22.18 GPa): a unit slip? give a unit, "
                  "e.g. --tau 22GPa", file=sys.stderr)  # fmt: skip
            return code

        run.warns_of_low_tau = True  # type: ignore[attr-defined]
        namespace.handler = run


def angle_rad(text: str) -> float:
    """argparse type: an angle, ``15deg`` or radians (``0.26``, ``0.26rad``) → rad."""
    return _quantity(text, _ANGLE_UNITS_RAD, "angle", "15deg")


def add_part_arguments(
    p: argparse.ArgumentParser, *, part_required: bool = True, example: str = "300x300x50"
) -> None:
    """``--part``, ``--support``, ``--surface`` and ``--density``."""
    p.add_argument(
        "--part",
        required=part_required,
        help=f"LxWxT in µm, e.g. {example}; sides {PART_SIDE_RANGE_UM[0]:g} µm–"
        f"{PART_SIDE_RANGE_UM[1]:g} µm, thickness {PART_THICKNESS_RANGE_UM[0]:g} µm–"
        f"{PART_THICKNESS_RANGE_UM[1]:g} µm",
    )
    p.add_argument("--support", default="flat", help="flat or grooved (default flat)")
    p.add_argument("--surface", type=input_path, help="surface TOML (default: the embedded surface)")
    p.add_argument(
        "--density",
        type=float_in(*DENSITY_RANGE_KG_M3),
        help=f"part density in kg/m³, {DENSITY_RANGE_KG_M3[0]:g}–{DENSITY_RANGE_KG_M3[1]:g} "
        f"(default the --material's, else silicon, {SILICON_DENSITY_KG_M3:g})",
    )
    p.add_argument(
        "--material",
        help="the part's material from the library (silicon, silica, glass, sapphire, steel, gold, "
        "pmma; docs/materials.md): its E, ν, hardness and density (default: the surface file's, silicon)",
    )
    p.add_argument(
        "--support-material",
        help="the support's material from the library (default: the part's); E* and the softer "
        "hardness come from the pair",
    )
    p.add_argument(
        "--adhesion-work",
        type=adhesion_work,
        metavar="J_M2",
        help=f"work of adhesion w in J/m², {ADHESION_WORK_HELP}, for Maugis–Dugdale adhesion per "
        "summit (default: "
        "the surface file's, else 0 as in the paper); τ is then the one fitted with w",
    )


def add_tau_arguments(p: argparse.ArgumentParser, *, band: bool = True) -> None:
    """``--tau``, ``--tau-adhesion-work`` (and ``--tau-band``); None = the τ fitted with the surface's w."""
    from feeder.contact.breakaway import DEFAULT_TAU_BAND_PA, DEFAULT_TAU_PA

    p.add_argument(
        "--tau",
        type=positive_pressure_pa,
        action=_ShearStrengthAction,
        help=f"interfacial shear strength, > 0, in Pa or with a unit (Pa, kPa, MPa, GPa: 22GPa); "
        f"below 1 kPa warns of a unit slip (default: the paper's, {DEFAULT_TAU_PA:g} Pa "
        "at w = 0, fitted again with the surface's w when it has one)",
    )
    p.add_argument(
        "--tau-adhesion-work",
        type=adhesion_work,
        metavar="J_M2",
        help="the w the given --tau was fitted with (default 0); must equal the contact's w",
    )
    if band:
        p.add_argument(
            "--tau-band",
            type=pressure_pa,
            help=f"± band of τ in Pa or with a unit like --tau (default "
            f"{DEFAULT_TAU_BAND_PA / DEFAULT_TAU_PA:.3g}·τ)",
        )


def materials_from(args: argparse.Namespace) -> tuple[Material | None, Material | None]:
    """The ``--material`` and ``--support-material`` (None where not given)."""
    from feeder.materials import material

    out: list[Material | None] = []
    for option in ("material", "support_material"):
        name = getattr(args, option, None)
        try:
            out.append(None if name is None else material(name))
        except InputError as err:
            raise InputError("--" + option.replace("_", "-"), err.message) from None
    return out[0], out[1]


def surface_from(args: argparse.Namespace) -> SurfaceParameters:
    """The ``--surface`` file (or the embedded default), with the materials and
    ``--adhesion-work`` applied."""
    from feeder.surface.parameters import DEFAULT_SURFACE, load_surface

    surface = load_surface(args.surface) if args.surface else DEFAULT_SURFACE
    part_material, support_material = materials_from(args)
    if part_material is not None:
        surface = replace(
            surface,
            youngs_modulus_pa=part_material.youngs_modulus_pa,
            poisson_ratio=part_material.poisson_ratio,
            hardness_pa=part_material.hardness_pa,
            support_youngs_modulus_pa=None,
            support_poisson_ratio=None,
        )
    if support_material is not None:
        surface = replace(
            surface,
            support_youngs_modulus_pa=support_material.youngs_modulus_pa,
            support_poisson_ratio=support_material.poisson_ratio,
            hardness_pa=min(surface.hardness_pa, support_material.hardness_pa),
        )
    if getattr(args, "adhesion_work", None) is None:
        return surface
    try:
        return replace(surface, adhesion_work_j_m2=args.adhesion_work)
    except InputError as err:
        raise InputError("--adhesion-work", err.message) from None


def part_from(args: argparse.Namespace) -> tuple[Part, Support, SurfaceParameters]:
    """Part, support and surface from :func:`add_part_arguments`' options."""
    density = args.density
    if density is None:
        part_material = materials_from(args)[0]
        density = SILICON_DENSITY_KG_M3 if part_material is None else part_material.density_kg_m3
    return Part.parse(args.part, density_kg_m3=density), Support.parse(args.support), surface_from(args)


def pose(text: str) -> tuple[float, float, float]:
    """argparse type: ``X,Y,PSI`` (m, m, rad, or with units: ``1.5mm,0,10deg``), finite."""
    fields = text.split(",")
    if len(fields) != 3:
        raise argparse.ArgumentTypeError(f"expected three values X,Y,PSI (m, m, rad), got {text!r}")
    try:
        return length_m(fields[0]), length_m(fields[1]), angle_rad(fields[2])
    except argparse.ArgumentTypeError as err:
        raise argparse.ArgumentTypeError(f"X,Y,PSI {text!r}: {err}") from None
