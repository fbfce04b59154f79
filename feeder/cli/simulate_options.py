"""What ``feeder simulate`` accepts: the options' plate-scale ranges and types, and a design
file's ``[axis]`` and ``[prediction]`` reconciled with the options (defaults, warnings, refusals)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import Any

from feeder.cli.arguments import pose
from feeder.errors import InputError
from feeder.parts import Part, Support
from feeder.plate_axes import AXES
from feeder.pose import MAX_POSE_M as MAX_POSE_M  # the --pose range, for simulate.py's help
from feeder.pose import part_pose
from feeder.waveform import read_waveform_tables

# Plate-scale ranges of the options (stated in --help).  A stack strokes ~14 µm at 200 V
# (θ: 7 mrad over the 2 mm lever arm), a plate is a few cm across.  A part's pose: the daemon
# configuration's (feeder.pose.part_pose), the same for every pose a user gives.
MAX_STROKE_M = 1e-3
MAX_STROKE_RAD = 0.1
MAX_MAP_EXTENT_M = 0.1
FREQUENCY_RANGE_HZ = (1e-3, 1e6)
MIN_FLYBACK_S = 1e-9
MAP_POINTS_RANGE = (2, 41)


def positive_up_to(parse: Callable[[str], float], high: float, unit: str) -> Callable[[str], float]:
    """argparse type: ``parse(text)`` in (0, ``high``]."""

    def parse_in(text: str) -> float:
        value = parse(text)
        if not 0 < value <= high:
            raise argparse.ArgumentTypeError(
                f"must be above 0 and at most {high:g} {unit}, got {text[:40]!r}"
            )
        return value

    return parse_in


def flyback_s(text: str) -> float:
    """argparse type: a flyback duration ≥ MIN_FLYBACK_S in s (checked against the period later)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text[:40]!r}") from None
    if not (math.isfinite(value) and value >= MIN_FLYBACK_S):
        raise argparse.ArgumentTypeError(
            f"must be from {MIN_FLYBACK_S:g} s to below the period 1/f, got {text[:40]!r}"
        )
    return value


def plate_pose(text: str) -> tuple[float, float, float]:
    """argparse type: ``X,Y,PSI`` (m, m, rad, or with units: ``1.5mm,0,10deg``), a part's pose
    on the plate (:func:`~feeder.pose.part_pose`: |X|, |Y| ≤ 0.1 m, |PSI| ≤ 2π)."""
    try:
        return part_pose(pose(text), "X,Y,PSI", repr(text[:40]))
    except InputError as err:
        raise argparse.ArgumentTypeError(err.message) from None


def design_defaults(args: argparse.Namespace) -> tuple[dict[str, Any], list[str]]:
    """Fill --axis and --pose from the --waveform design file's ``[axis]`` table (else x, 0,0,0).

    Returns the file's ``[prediction]`` table (empty for a plain waveform file) and a warning
    for each of --axis, --pose given against the file's ``[axis]``: the pose only where the
    prediction depends on it (θ; a translation steps the same anywhere on the plate).
    """
    tables = read_waveform_tables(args.waveform) if args.waveform is not None else {}
    axis_table, prediction = tables.get("axis", {}), tables.get("prediction", {})
    file_axis, file_pose = axis_table.get("name"), axis_table.get("pose")
    if file_axis is not None and file_axis not in AXES:
        raise InputError(
            f"{args.waveform}: [axis].name", f"must be one of {', '.join(AXES)}, got {file_axis!r}"
        )
    if file_pose is not None:
        field = f"{args.waveform}: [axis].pose"
        if not isinstance(file_pose, list) or not all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in file_pose
        ):
            raise InputError(field, f"expected [X, Y, PSI] in m, m, rad, got {file_pose!r}")
        file_pose = part_pose([float(v) for v in file_pose], field, repr(file_pose))
    warnings: list[str] = []
    args.axis_from_file = args.axis is None and file_axis is not None
    if args.axis is None:
        args.axis = file_axis or "x"
    elif file_axis is not None and args.axis != file_axis:
        warnings.append(f"--axis {args.axis} contradicts {args.waveform}'s [axis] name = {file_axis!r}: "
                        f"its waveform and prediction are for axis {file_axis}")  # fmt: skip
    if args.pose is None:
        args.pose = file_pose or (0.0, 0.0, 0.0)
    elif (
        file_pose is not None
        and args.axis == "theta"
        and file_axis == "theta"
        and not all(
            math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12) for a, b in zip(args.pose, file_pose, strict=True)
        )
    ):
        warnings.append(f"--pose {_pose_text(args.pose)} contradicts {args.waveform}'s [axis] pose "
                        f"{_pose_text(file_pose)}: its θ prediction holds at that pose only")  # fmt: skip
    return prediction, warnings


def _pose_text(values: tuple[float, ...]) -> str:
    return ",".join(f"{v:g}" for v in values)


def prediction_warnings(args: argparse.Namespace, prediction: dict[str, Any], part: Part,
                         support: Support) -> list[str]:  # fmt: skip
    """A warning for --part (and --support) against the design file's ``[prediction]``."""
    warnings = []
    file_part = prediction.get("part")
    if isinstance(file_part, str):
        try:
            same = Part.parse(file_part).label == part.label
        except InputError:
            same = file_part.strip() == args.part.strip()
        if not same:
            warnings.append(f"--part {part.label} contradicts {args.waveform}'s [prediction] part = "
                            f"{file_part!r}: its predicted step is for that part")  # fmt: skip
    file_support = prediction.get("support")
    if isinstance(file_support, str) and file_support.strip().lower() != support.kind:
        warnings.append(f"--support {support.kind} contradicts {args.waveform}'s [prediction] support = "
                        f"{file_support!r}: its predicted step is for that support")  # fmt: skip
    return warnings


def refuse_ignored_drive_options(args: argparse.Namespace) -> None:
    """The ideal plate's drive options where nothing would read them: without --ideal the plant
    plays --waveform; with --ideal and --waveform, the file gives frequency and flyback (a
    stroke may still be given); each axis reads its own stroke; the ideal plate has no scatter."""
    options = {"--stroke-m": args.stroke_m, "--stroke-rad": args.stroke_rad,
               "--frequency-hz": args.frequency_hz, "--flyback-s": args.flyback_s}  # fmt: skip
    for flag in (flag for flag, value in options.items() if value is not None):
        if not args.ideal:
            raise InputError(flag, "only with --ideal: the plant plays --waveform's drive")
        if args.waveform is not None and flag in ("--frequency-hz", "--flyback-s"):
            raise InputError(flag, f"not with --waveform: {args.waveform} gives the frequency and flyback")
        if flag == "--stroke-m" and args.axis == "theta":
            raise InputError(flag, "for --axis x or y; θ's stroke is --stroke-rad")
        if flag == "--stroke-rad" and args.axis != "theta":
            raise InputError(flag, f"for --axis theta; axis {args.axis}'s stroke is --stroke-m")
    if args.scatter > 0 and args.ideal:
        raise InputError(
            "--scatter", "only for the plant (--waveform without --ideal): the ideal plate has none"
        )
