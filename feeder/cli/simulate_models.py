"""What ``feeder simulate`` runs: the plant or the ideal plate on x or y, the planar solver or
the planar plant on θ, and the ``--map`` of pose changes over a grid of poses (DESIGN §4)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from feeder.cli.waveform import file_amplifier, file_stack, load_checked
from feeder.errors import InputError, check_memory_budget
from feeder.files import save_figure
from feeder.parts import Part
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.ideal_plate import linear_flyback_step, sawtooth_motion
from feeder.plant.planar import PlanarPart, simulate
from feeder.plant.plant import BYTES_PER_SAMPLE, DEFAULT_SAMPLE_RATE_HZ, run_waveform
from feeder.plant.plate_motion import sawtooth
from feeder.plant.stick_slip import Friction, StickSlip
from feeder.plate_axes import AXES
from feeder.waveform import Waveform, read_waveform_tables


def _sawtooth_parameters(args: argparse.Namespace, stroke: float | None) -> tuple[
        float, float, float, str, str]:  # fmt: skip
    """(stroke, frequency, flyback, flyback shape, direction) of the ideal plate.

    From --waveform (stroke = stack gain × amplitude, or ``stroke`` when given;
    a current-limited flyback becomes the linear ramp the amplifier makes, with
    the swing it reaches) or from --stroke-m/--stroke-rad, --frequency-hz, --flyback-s.
    """
    stroke_flag = "--stroke-rad" if args.axis == "theta" else "--stroke-m"
    if args.waveform is not None:
        amplifier, stack = file_amplifier(args.waveform), file_stack(args.waveform)
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


def unfollowed_flyback(path: Path) -> str | None:
    """A warning when the --waveform file's command flies back faster than its amplifier can follow
    (into the file's stack), else None.

    The ideal plate follows the command's flyback by design; the amplifier (``feeder waveform
    show``, the plant) makes the current-limited flyback instead, over a smaller swing.
    """
    from feeder.design import fastest_flyback_s

    amplifier, stack = file_amplifier(path), file_stack(path)
    waveform = load_checked(path, amplifier)
    command = waveform.command_flyback_s
    if not command:  # current-limited: the ideal plate already takes the amplifier's flyback
        return None
    fastest = fastest_flyback_s(waveform.flyback_shape, waveform.amplitude_vpp, amplifier, stack)
    if command >= fastest:
        return None
    t_f, fraction = amplifier.current_limited_flyback(
        waveform.amplitude_vpp, waveform.frequency_hz, stack.capacitance_f
    )
    swing_v = float(fraction) * waveform.amplitude_vpp
    return (
        f"{path}: the amplifier cannot follow the command's {command * 1e6:.4g} µs {waveform.flyback_shape} "
        f"flyback into the {stack.capacitance_f:g} F stack: it flies back in {float(t_f) * 1e6:.4g} µs, "
        f"current-limited, over {swing_v:.4g} V of {waveform.amplitude_vpp:.4g} V (as `feeder waveform show` "
        f"reports); the ideal plate follows the command's {command * 1e6:.4g} µs flyback, and `feeder "
        "simulate` without --ideal gives what the plate does"
    )


def ideal(args: argparse.Namespace, friction: Friction) -> tuple[
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


def plant(args: argparse.Namespace, friction: Friction) -> tuple[
        np.ndarray, float, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:  # fmt: skip
    """--waveform on the plant (amplifier, stack, stick-slip), x or y axis."""
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
    run_ = run_waveform(friction, waveform, args.periods, amplifier, file_stack(args.waveform),
                        scatter=args.scatter, seed=args.seed, oversample=oversample)  # fmt: skip
    extra = {"model": "plant", "waveform": str(args.waveform), "oversample": oversample}
    return run_.steps_m, run_.slip_fraction, run_.time_s, run_.part_position_m, run_.plate_position_m, extra


def _strokes(args: argparse.Namespace) -> tuple[tuple[float, float, float], float, float, str]:
    """Signed (S_x, S_y, S_θ), frequency, flyback, shape for the driven axis; θ's stroke from
    --stroke-rad, else --waveform's stroke over its θ lever arm ([axis] lever_arm_m)."""
    if args.axis == "theta" and args.stroke_rad is None and args.waveform is None:
        raise InputError("--stroke-rad", "required with --axis theta (or give --waveform)")
    given = args.stroke_rad if args.axis == "theta" else args.stroke_m
    if given is None and args.axis == "theta":  # the stack's full stroke (m) at the lever arm → rad
        _, waveform, lever_arm_m = _planar_plant_drive(args)
        given = file_stack(args.waveform).gain_m_per_v * waveform.amplitude_vpp / lever_arm_m
    stroke, frequency, flyback, shape, direction = _sawtooth_parameters(args, given)
    signed = stroke if direction == "forward" else -stroke
    strokes = [0.0, 0.0, 0.0]
    strokes[AXES.index(args.axis)] = signed
    return (strokes[0], strokes[1], strokes[2]), frequency, flyback, shape


def theta(args: argparse.Namespace, part: Part, friction: Friction) -> tuple[
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


def theta_plant(args: argparse.Namespace, part: Part, friction: Friction) -> tuple[
        np.ndarray, float, np.ndarray, dict[str, Any]]:  # fmt: skip
    """The waveform on the θ channel of the planar plant (amplifier, stack, planar stick-slip)."""
    from feeder.axis_design import run_axis_waveform

    if args.scatter > 0:
        raise InputError("--scatter", "the planar plant has no scatter (--axis theta)")
    amplifier, waveform, lever_arm_m = _planar_plant_drive(args)
    planar = PlanarPart.from_part(part, friction, args.pose, args.part_shape)
    run_ = run_axis_waveform(planar, waveform, "theta", args.periods, amplifier, file_stack(args.waveform),
                             lever_arm_m=lever_arm_m)  # fmt: skip
    extra = {"model": "planar-plant", "waveform": str(args.waveform), "part_shape": args.part_shape,
             "lever_arm_m": lever_arm_m}  # fmt: skip
    return run_.steps_m, run_.slip_fraction, run_.poses[1:], extra


MAP_PROGRESS_S = 2.0
"""A --map that runs longer prints its progress to stderr this often (s)."""


def pose_map(args: argparse.Namespace, part: Part, friction: Friction) -> list[list[float]]:
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
