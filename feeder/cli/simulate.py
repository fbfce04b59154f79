"""``feeder simulate``: step size of a waveform on a part, full plant or ideal plate (DESIGN §4):
its options, the checks across them and its report; what it runs is in :mod:`~feeder.cli.simulate_models`."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np

from feeder.cli.arguments import (
    add_part_arguments,
    add_tau_arguments,
    angle_rad,
    float_in,
    input_path,
    int_in,
    length_m,
    output_path,
    part_from,
    positive_float,
)
from feeder.cli.output import print_json
from feeder.cli.simulate_models import ideal, plant, pose_map, theta, theta_plant, unfollowed_flyback
from feeder.cli.simulate_options import (
    FREQUENCY_RANGE_HZ,
    MAP_POINTS_RANGE,
    MAX_MAP_EXTENT_M,
    MAX_POSE_M,
    MAX_STROKE_M,
    MAX_STROKE_RAD,
    MIN_FLYBACK_S,
    design_defaults,
    flyback_s,
    plate_pose,
    positive_up_to,
    prediction_warnings,
    refuse_ignored_drive_options,
)
from feeder.contact.breakaway import contact
from feeder.errors import InputError
from feeder.files import save_figure
from feeder.plant.plant import MAX_OVERSAMPLE, MAX_PERIODS
from feeder.plant.steady_state import steady_start
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO, MAX_SCATTER, Friction
from feeder.plate_axes import AXES
from feeder.waveform import DIRECTIONS


def register(sub: Any) -> None:
    p = sub.add_parser("simulate", help="simulate a part stepping on the plate")
    add_part_arguments(p, example="500x500x50")
    add_tau_arguments(p, band=False)
    p.add_argument(
        "--kinetic-ratio",
        type=positive_float,
        default=DEFAULT_KINETIC_RATIO,
        help=f"F_k/F_s, above 0 and at most 1 (default {DEFAULT_KINETIC_RATIO})",
    )
    p.add_argument("--waveform", type=input_path, help="waveform TOML (full plant, or --ideal)")
    p.add_argument(
        "--periods",
        type=int_in(1, MAX_PERIODS),
        default=20,
        help=f"periods to simulate, 1–{MAX_PERIODS:.0e} (default 20; the plant's traces must "
        "also fit the 2 GiB memory budget)",
    )
    p.add_argument(
        "--scatter",
        type=float,
        default=0.0,
        help="relative step-to-step scatter of a_s (1σ), 0–0.5, e.g. 0.05 for 5 %% (plant only, default 0)",
    )
    p.add_argument("--seed", type=int_in(0, 2**63 - 1), help="seed for --scatter (non-negative)")
    p.add_argument(
        "--oversample",
        type=int_in(1, MAX_OVERSAMPLE),
        help=f"stack and contact steps per DAC sample, 1–{MAX_OVERSAMPLE} (plant, axis x or y; default 1: "
        "the DAC's 100 kS/s, 2 %% off converged for the paper's waveform; ≥ 20 converges, docs/plant.md)",
    )
    p.add_argument(
        "--ideal",
        action="store_true",
        help="ideal plate: follows the sawtooth exactly (no amplifier, no stack)",
    )
    p.add_argument(
        "--stroke-m",
        type=positive_up_to(length_m, MAX_STROKE_M, "m"),
        metavar="S",
        help=f"ideal plate, --axis x or y: stroke S in m (or 5um, 0.01mm), 0 < S ≤ {MAX_STROKE_M:g} m "
        "(--direction backward for the other sign)",
    )
    p.add_argument(
        "--frequency-hz",
        type=float_in(*FREQUENCY_RANGE_HZ),
        help=f"ideal plate: frequency in Hz, {FREQUENCY_RANGE_HZ[0]:g}–{FREQUENCY_RANGE_HZ[1]:g}",
    )
    p.add_argument(
        "--flyback-s",
        type=flyback_s,
        help=f"ideal plate: flyback duration t_f in s, from {MIN_FLYBACK_S:g} s to below the period "
        "1/f (above half the period the closed form does not apply)",
    )
    p.add_argument(
        "--flyback-shape",
        default="linear",
        choices=("linear", "half-cosine"),
        help="ideal plate: flyback shape (default linear)",
    )
    p.add_argument(
        "--direction", default="forward", choices=DIRECTIONS, help="ideal plate: direction (default forward)"
    )
    p.add_argument(
        "--axis",
        choices=AXES,
        help="driven plate axis: x, y or theta about O (default: the --waveform design file's "
        "[axis] name, else x)",
    )
    p.add_argument(
        "--pose",
        type=plate_pose,
        metavar="X,Y,PSI",
        help=f"part pose in the plate frame, origin at O: m, m, rad; |X|, |Y| ≤ {MAX_POSE_M:g} m, "
        "|PSI| ≤ 2π (default: the --waveform design file's [axis] pose, else 0,0,0)",
    )
    p.add_argument(
        "--stroke-rad",
        type=positive_up_to(angle_rad, MAX_STROKE_RAD, "rad"),
        metavar="THETA",
        help=f"ideal plate, --axis theta: stroke in rad (or 0.4deg), 0 < THETA ≤ {MAX_STROKE_RAD:g} rad",
    )
    p.add_argument(
        "--part-shape",
        default="rectangle",
        choices=("rectangle", "disc"),
        help="footprint for --axis theta: rectangle LxW or disc of diameter L (default rectangle)",
    )
    p.add_argument(
        "--map",
        type=output_path,
        metavar="PNG",
        help="quiver plot of the per-period pose change (the second period) over a grid of poses "
        "(the planar plant with --waveform, else the ideal plate)",
    )
    p.add_argument(
        "--map-extent-m",
        type=positive_up_to(length_m, MAX_MAP_EXTENT_M, "m"),
        default=2.5e-3,
        help=f"--map: grid half-width around O in m (or 3mm), above 0 and at most {MAX_MAP_EXTENT_M:g} m "
        "(default 2.5e-3)",
    )
    p.add_argument(
        "--map-points",
        type=int_in(*MAP_POINTS_RANGE),
        default=11,
        help=f"--map: grid points per side, {MAP_POINTS_RANGE[0]}–{MAP_POINTS_RANGE[1]} (default 11)",
    )
    p.add_argument("--plot", type=output_path, metavar="PNG", help="plot part and plate position (x or y)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if not args.kinetic_ratio <= 1:
        raise InputError("--kinetic-ratio", f"must lie in (0, 1], got {args.kinetic_ratio}")
    if not 0 <= args.scatter <= MAX_SCATTER:
        raise InputError("--scatter", f"must lie in [0, {MAX_SCATTER:g}] (0.05 is 5 %), got {args.scatter}")
    prediction, notes = design_defaults(args)
    refuse_ignored_drive_options(args)
    from_file = f" (from {args.waveform}'s [axis])" if args.axis_from_file else ""
    if args.axis == "theta" and not args.ideal and args.waveform is None:
        raise InputError("--waveform", "required with --axis theta unless --ideal")
    if args.map is not None and not args.ideal and args.waveform is None:
        raise InputError("--map", "needs --waveform (the planar plant) or --ideal")
    if args.map is not None and not args.ideal and args.scatter > 0:
        raise InputError("--scatter", "the planar plant behind --map has no scatter")
    if args.oversample is not None and (args.ideal or args.axis == "theta" or args.map is not None):
        raise InputError("--oversample", "only for the plant on axis x or y (not --ideal, theta or --map)")
    if args.axis == "theta" and args.plot:
        raise InputError("--plot", f"traces are for --axis x or y, not theta{from_file}; use --map for theta")
    part, support, surface = part_from(args)
    notes += prediction_warnings(args, prediction, part, support)
    # the ideal plate follows the command's flyback; one the amplifier cannot follow is no plate's
    flyback = unfollowed_flyback(args.waveform) if args.ideal and args.waveform is not None else None
    result = contact(part, support, surface, args.tau)
    friction = Friction(result.breakaway_accel_m_s2, args.kinetic_ratio)
    out: dict[str, Any] = {"part": part.label, "support": args.support,
                           "breakaway_accel_m_s2": friction.static_accel_m_s2,
                           "kinetic_accel_m_s2": friction.kinetic_accel_m_s2,
                           "axis": args.axis}  # fmt: skip
    plot = None
    if args.axis == "theta" and not args.ideal:
        steps, slip_fraction, poses, extra = theta_plant(args, part, friction)
    elif args.axis == "theta":
        steps, slip_fraction, poses, extra = theta(args, part, friction)
    else:
        steps, slip_fraction, time, part_x, plate_x, extra = (ideal if args.ideal else plant)(args, friction)
        plot = (time, part_x, plate_x)
        # a translation moves the part along the driven axis of the plate, whatever its ψ
        poses = np.tile(np.asarray(args.pose, dtype=float), (steps.size, 1))
        poses[:, 0 if args.axis == "x" else 1] += np.cumsum(steps)
    out.update(extra)
    if args.ideal:  # always present: null when the flyback has no closed form (half-cosine, theta)
        out.setdefault("closed_form_step_m", None)
    transient, settled = _transient(args, steps, notes)
    steady = steps[transient:]
    out.update(
        {
            "transient_periods": transient,
            "steady": settled,
            "step_mean_m": float(np.mean(steady)),
            "step_std_m": float(np.std(steady, ddof=1)) if steady.size > 1 else 0.0,
            "first_step_m": float(steps[0]),
            "net_displacement_m": float(np.sum(steps)),
            "periods": int(steps.size),
            "slip_fraction": slip_fraction,
            "steps_m": steps,
            "pose_start": list(args.pose),
            "poses": poses,
            "warnings": [*notes, *result.warnings, *([flyback] if flyback else [])],
        }
    )
    if args.axis == "theta":
        turns = np.diff(np.concatenate(([args.pose[2]], poses[:, 2])))
        out["turns_rad"] = turns
        out["turn_mean_rad"] = float(np.mean(turns[1:] if turns.size > 1 else turns))
    if args.plot and plot is not None:
        _plot(*plot, args.plot)
        out["plot"] = str(args.plot)
    if args.map is not None:
        out["map_pose_changes"] = pose_map(args, part, friction)
        out["map"] = str(args.map)
    if args.json:
        print_json(out)
    else:
        print(
            f"part {part.label} µm, a_s {friction.static_accel_m_s2:.4g} m/s², "
            f"a_k {friction.kinetic_accel_m_s2:.4g} m/s² ({out['model']}, axis {args.axis})"
        )
        print(
            f"  step   {out['step_mean_m'] * 1e6:.4f}{_spread(out)} µm "
            f"({_steady_label(out['transient_periods'], out['steady'])}; "
            f"first period {out['first_step_m'] * 1e6:.4f} µm) "
            f"over {out['periods']} periods"
        )
        if "turn_mean_rad" in out:
            print(f"  turn   {out['turn_mean_rad'] * 1e3:.4f} mrad per period")
        print(f"  pose   {' '.join(f'{v:.6g}' for v in poses[-1])} (m, m, rad) after the last period")
        print(
            f"  net    {out['net_displacement_m'] * 1e6:.4f} µm, slipping "
            f"{100 * slip_fraction:.2f} % of the time"
        )
        closed = out.get("closed_form_step_m")
        if closed is not None:
            print(f"  closed form {closed * 1e6:.6f} µm" if math.isfinite(closed) else
                  "  closed form n/a (flyback longer than the rise: the part need not re-stick)")  # fmt: skip
        for warning in out["warnings"]:
            print(f"  warning: {warning}")
        for key in ("plot", "map"):
            if key in out:
                print(f"wrote {out[key]}")
    return 0


def _spread(out: dict[str, Any]) -> str:
    """The std over the steady periods, as " ± x"; none for one period (± 0 would claim a certainty)."""
    counted = out["periods"] - out["transient_periods"]
    return f" ± {out['step_std_m'] * 1e6:.4f}" if counted > 1 else ""


def _steady_label(transient: int, settled: bool | None) -> str:
    """What ``step`` averages: the steady state, the last period (not settled), or, not judged
    (θ, scatter: ``steady`` null), the periods after the first."""
    if settled is False:
        return "NOT settled: the last period"
    if settled is None:
        return "after the first period, steadiness not judged"
    return "steady state" + (f" from period {transient + 1}" if transient > 1 else "")


def _transient(args: argparse.Namespace, steps: np.ndarray, notes: list[str]) -> tuple[int, bool | None]:
    """(periods before the steady state, whether the run shows it): x and y without scatter by
    :func:`~feeder.plant.steady_state.steady_start`, with a note when the steps still drift;
    θ (the step changes with the pose) and scatter: the first period, not judged (None)."""
    if args.axis == "theta" or args.scatter > 0 or steps.size < 2:
        return min(1, steps.size - 1), None
    start, settled = steady_start(steps)
    if steps.size < 3:
        notes.append(f"{steps.size} periods cannot show the steady state (that takes 3): run more --periods")
    elif not settled[0]:
        um = ", ".join(f"{1e6 * v:.4g}" for v in steps[-3:])
        notes.append(
            f"the step has not settled in {steps.size} periods (the last: {um} µm; the part slides "
            f"through whole periods): step_mean_m is not the steady state; run more --periods"
        )
    return int(start[0]), bool(settled[0])


def _plot(time: np.ndarray, part: np.ndarray, plate: np.ndarray, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(time * 1e3, plate * 1e6, label="plate")
    ax.plot(time * 1e3, part * 1e6, label="part")
    ax.set_xlabel("time (ms)")
    ax.set_ylabel("position (µm)")
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)
