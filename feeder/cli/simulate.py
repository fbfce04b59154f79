"""``feeder simulate``: step size of a waveform on a part, full plant or ideal plate (DESIGN §4)."""

from __future__ import annotations

import argparse
import math
import sys
import time
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
from feeder.cli.waveform import file_amplifier, load_checked
from feeder.contact.breakaway import contact
from feeder.errors import InputError, check_memory_budget
from feeder.files import save_figure
from feeder.parts import Part
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.ideal_plate import linear_flyback_step, sawtooth_motion
from feeder.plant.planar import PlanarPart, simulate
from feeder.plant.plant import (
    BYTES_PER_SAMPLE,
    DEFAULT_SAMPLE_RATE_HZ,
    MAX_OVERSAMPLE,
    MAX_PERIODS,
    run_waveform,
)
from feeder.plant.plate_motion import sawtooth
from feeder.plant.stack import StackParameters
from feeder.plant.steady_state import steady_start
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO, MAX_SCATTER, Friction, StickSlip
from feeder.plate_axes import AXES
from feeder.waveform import DIRECTIONS, Waveform, read_waveform_tables


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
    result = contact(part, support, surface, args.tau)
    friction = Friction(result.breakaway_accel_m_s2, args.kinetic_ratio)
    out: dict[str, Any] = {"part": part.label, "support": args.support,
                           "breakaway_accel_m_s2": friction.static_accel_m_s2,
                           "kinetic_accel_m_s2": friction.kinetic_accel_m_s2,
                           "axis": args.axis}  # fmt: skip
    plot = None
    if args.axis == "theta" and not args.ideal:
        steps, slip_fraction, poses, extra = _theta_plant(args, part, friction)
    elif args.axis == "theta":
        steps, slip_fraction, poses, extra = _theta(args, part, friction)
    else:
        if args.ideal:
            steps, slip_fraction, time, part_x, plate_x, extra = _ideal(args, friction)
        else:
            if args.waveform is None:
                raise InputError("--waveform", "required unless --ideal")
            if args.scatter > 0 and args.seed is None:
                args.seed = 0
            amplifier = file_amplifier(args.waveform)  # a design file's [amplifier], else the default
            waveform = load_checked(args.waveform, amplifier)
            oversample = args.oversample or 1
            samples = (args.periods + 1) * round(DEFAULT_SAMPLE_RATE_HZ / waveform.frequency_hz)
            check_memory_budget("--periods", samples * oversample * BYTES_PER_SAMPLE)
            if not args.json:
                finer = f", {oversample} steps per sample" if oversample > 1 else ""
                print(f"simulating {args.periods} periods at 100 kS/s{finer} ...", file=sys.stderr)
            run_ = run_waveform(friction, waveform, args.periods, amplifier, scatter=args.scatter,
                                seed=args.seed, oversample=oversample)  # fmt: skip
            steps, slip_fraction = run_.steps_m, run_.slip_fraction
            time, part_x, plate_x = run_.time_s, run_.part_position_m, run_.plate_position_m
            extra = {"model": "plant", "waveform": str(args.waveform), "oversample": oversample}
        plot = (time, part_x, plate_x)
        # a translation moves the part along the driven axis of the plate, whatever its ψ
        poses = np.tile(np.asarray(args.pose, dtype=float), (steps.size, 1))
        poses[:, 0 if args.axis == "x" else 1] += np.cumsum(steps)
    out.update(extra)
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
            "warnings": [*notes, *result.warnings],
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
        out["map_pose_changes"] = _map(args, part, friction)
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
        if "closed_form_step_m" in out:
            closed = out["closed_form_step_m"]
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
    if settled is False:
        return "NOT settled: the last period"
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


def _sawtooth_parameters(args: argparse.Namespace, stroke: float | None) -> tuple[
        float, float, float, str, str]:  # fmt: skip
    """(stroke, frequency, flyback, flyback shape, direction) of the ideal plate.

    From --waveform (stroke = stack gain × amplitude, or ``stroke`` when given;
    a current-limited flyback becomes the linear ramp the amplifier makes, with
    the swing it reaches) or from --stroke-m/--stroke-rad, --frequency-hz, --flyback-s.
    """
    stroke_flag = "--stroke-rad" if args.axis == "theta" else "--stroke-m"
    if args.waveform is not None:
        amplifier, stack = AmplifierLimits(), StackParameters()
        waveform = load_checked(args.waveform, amplifier)
        full = stroke if stroke is not None else stack.gain_m_per_v * waveform.amplitude_vpp
        frequency, direction = waveform.frequency_hz, waveform.direction
        if waveform.flyback_shape == "current-limited":
            t_f, fraction = amplifier.current_limited_flyback(
                waveform.amplitude_vpp, frequency, stack.capacitance_f)  # fmt: skip
            return full * float(fraction), frequency, float(t_f), "linear", direction
        return full, frequency, waveform.command_flyback_s, waveform.flyback_shape, direction
    for name, flag in ((stroke, stroke_flag), (args.frequency_hz, "--frequency-hz"),
                       (args.flyback_s, "--flyback-s")):  # fmt: skip
        if name is None:
            raise InputError(flag, "required with --ideal (or give --waveform)")
    assert stroke is not None
    if args.flyback_s >= 1.0 / args.frequency_hz:
        raise InputError(
            "--flyback-s", f"{args.flyback_s:g} s is not shorter than the period {1 / args.frequency_hz:g} s"
        )
    return stroke, args.frequency_hz, args.flyback_s, args.flyback_shape, args.direction


def _strokes(args: argparse.Namespace) -> tuple[tuple[float, float, float], float, float, str]:
    """Signed (S_x, S_y, S_θ), frequency, flyback, shape for the driven axis; θ's stroke from
    --stroke-rad, else --waveform's stroke over its θ lever arm ([axis] lever_arm_m)."""
    if args.axis == "theta" and args.stroke_rad is None and args.waveform is None:
        raise InputError("--stroke-rad", "required with --axis theta (or give --waveform)")
    given = args.stroke_rad if args.axis == "theta" else args.stroke_m
    if given is None and args.axis == "theta":  # the stack's full stroke (m) at the lever arm → rad
        _, waveform, lever_arm_m = _planar_plant_drive(args)
        given = StackParameters().gain_m_per_v * waveform.amplitude_vpp / lever_arm_m
    stroke, frequency, flyback, shape, direction = _sawtooth_parameters(args, given)
    signed = stroke if direction == "forward" else -stroke
    strokes = [0.0, 0.0, 0.0]
    strokes[AXES.index(args.axis)] = signed
    return (strokes[0], strokes[1], strokes[2]), frequency, flyback, shape


def _theta(args: argparse.Namespace, part: Part, friction: Friction) -> tuple[
        np.ndarray, float, np.ndarray, dict[str, Any]]:  # fmt: skip
    """The planar solver on one part: per-period distance moved, slip fraction, poses, extra keys."""
    strokes, frequency, flyback, shape = _strokes(args)
    planar = PlanarPart.from_part(part, friction, args.pose, args.part_shape)
    run_ = simulate([planar], sawtooth(strokes, frequency, flyback, shape, args.periods))
    steps = np.hypot(run_.changes[0, :, 0], run_.changes[0, :, 1])
    extra: dict[str, Any] = {
        "model": "ideal-planar",
        "stroke_rad": strokes[2],
        "frequency_hz": frequency,
        "flyback_s": flyback,
        "flyback_shape": shape,
        "part_shape": args.part_shape,
    }
    return steps, float(run_.slip_fraction[0]), run_.poses[0], extra


def _planar_plant_drive(args: argparse.Namespace) -> tuple[AmplifierLimits, Waveform, float]:
    """The amplifier, waveform and θ lever arm (m) of --waveform (its [axis] table, else the
    plant's default) for the planar plant."""
    from feeder.plant.planar_plant import DEFAULT_LEVER_ARM_M

    amplifier = file_amplifier(args.waveform)
    waveform = load_checked(args.waveform, amplifier)
    lever_arm_m = read_waveform_tables(args.waveform).get("axis", {}).get("lever_arm_m", DEFAULT_LEVER_ARM_M)
    return amplifier, waveform, float(lever_arm_m)


def _theta_plant(args: argparse.Namespace, part: Part, friction: Friction) -> tuple[
        np.ndarray, float, np.ndarray, dict[str, Any]]:  # fmt: skip
    """The waveform on the θ channel of the planar plant (amplifier, stack, planar stick-slip)."""
    from feeder.axis_design import run_axis_waveform

    if args.scatter > 0:
        raise InputError("--scatter", "the planar plant has no scatter (--axis theta)")
    amplifier, waveform, lever_arm_m = _planar_plant_drive(args)
    planar = PlanarPart.from_part(part, friction, args.pose, args.part_shape)
    run_ = run_axis_waveform(planar, waveform, "theta", args.periods, amplifier, lever_arm_m=lever_arm_m)
    extra = {"model": "planar-plant", "waveform": str(args.waveform), "part_shape": args.part_shape,
             "lever_arm_m": lever_arm_m}  # fmt: skip
    return run_.steps_m, run_.slip_fraction, run_.poses[1:], extra


MAP_PROGRESS_S = 2.0
"""A --map that runs longer prints its progress to stderr this often (s)."""


def _map(args: argparse.Namespace, part: Part, friction: Friction) -> list[list[float]]:
    """Steady-state pose change (the second period) at each grid pose; draws the quiver plot.

    With --waveform (not --ideal) the planar plant (amplifier, stack, planar stick-slip) driven
    on --axis; else the ideal plate's sawtooth.
    """
    grid = np.linspace(-args.map_extent_m, args.map_extent_m, args.map_points)
    points = [(float(x), float(y), float(args.pose[2])) for y in grid for x in grid]
    if args.ideal:
        strokes, frequency, flyback, shape = _strokes(args)
        motion = sawtooth(strokes, frequency, flyback, shape, 2)
        model = "ideal plate"

        def change(planar: PlanarPart) -> np.ndarray:
            return simulate([planar], motion).changes[0, -1]
    else:
        from feeder.axis_design import run_axis_waveform

        amplifier, waveform, lever_arm_m = _planar_plant_drive(args)
        model = f"planar plant, {args.waveform.name}"

        def change(planar: PlanarPart) -> np.ndarray:
            run_ = run_axis_waveform(planar, waveform, args.axis, 2, amplifier, lever_arm_m=lever_arm_m)
            return run_.pose_changes[-1]

    rows = []
    shown = time.monotonic()
    for point in points:
        dx, dy, dpsi = change(PlanarPart.from_part(part, friction, point, args.part_shape))
        rows.append([point[0], point[1], float(dx), float(dy), float(dpsi)])
        if time.monotonic() - shown > MAP_PROGRESS_S:  # long maps say how far they are
            print(f"feeder simulate: --map {len(rows)}/{len(points)} poses", file=sys.stderr, flush=True)
            shown = time.monotonic()
    _quiver(np.array(rows), args, args.map, model)
    return rows


def _quiver(rows: np.ndarray, args: argparse.Namespace, path: Path, model: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x, y, dx, dy, dpsi = rows.T
    fig, ax = plt.subplots(figsize=(6.4, 5.4))
    # a diverging map centred on no turn: one-signed turns (every θ map) run from white at 0 to the
    # full colour, never through white in the middle of their range (arrows of 2.5–3 mrad vanished)
    reach = float(np.max(np.abs(dpsi))) * 1e3 or 1.0
    quiver = ax.quiver(x * 1e3, y * 1e3, dx * 1e6, dy * 1e6, dpsi * 1e3, cmap="coolwarm",
                       norm=matplotlib.colors.Normalize(-reach, reach), angles="xy", pivot="mid")  # fmt: skip
    fig.colorbar(quiver, ax=ax, label="turn per period Δψ (mrad)")
    moved = np.hypot(dx, dy)
    if moved.max() > 0:
        ax.quiverkey(quiver, 0.75, -0.13, float(moved.max() * 1e6),
                     f"{moved.max() * 1e6:.3g} µm/period", labelpos="E")  # fmt: skip
    ax.plot([0], [0], "k+", ms=12)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_aspect("equal")
    ax.set_title(f"{args.part} µm, ψ = {args.pose[2]:g} rad, axis {args.axis}: pose change per period\n"
                 f"{model}", fontsize=9)  # fmt: skip
    fig.tight_layout()
    fig.subplots_adjust(bottom=0.15)  # room for the key below the x label
    save_figure(fig, path)


def _ideal(args: argparse.Namespace, friction: Friction) -> tuple[
        np.ndarray, float, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:  # fmt: skip
    """Ideal plate from --stroke-m/--frequency-hz/--flyback-s, or from --waveform (x or y axis)."""
    stroke, frequency, flyback, shape, direction = _sawtooth_parameters(args, args.stroke_m)
    sign = 1.0 if direction == "forward" else -1.0
    motion = sawtooth_motion(stroke, frequency, flyback, shape, args.periods, sign)
    solver = StickSlip(friction)
    rel = solver.advance(motion.accel_m_s2[0], motion.duration_s[0], motion.jump_m_s[0])
    per = motion.intervals_per_period
    steps = np.diff(np.concatenate(([0.0], rel[per - 1 :: per])))
    ends = np.cumsum(motion.duration_s[0])
    time = np.concatenate(([0.0], ends))
    plate = np.concatenate(([sign * stroke], motion.position_m[0]))
    part_x = plate + np.concatenate(([0.0], rel))
    extra: dict[str, Any] = {
        "model": "ideal",
        "stroke_m": stroke,
        "frequency_hz": frequency,
        "flyback_s": flyback,
        "flyback_shape": shape,
        "direction": direction,
    }
    if shape == "linear":
        extra["closed_form_step_m"] = sign * float(linear_flyback_step(
            stroke, 1.0 / frequency - flyback, flyback, friction.kinetic_accel_m_s2))  # fmt: skip
    return steps, solver.slip_time_s / solver.elapsed_s, time, part_x, plate, extra


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
