"""``feeder simulate``: step size of a waveform on a part, full plant or ideal plate (DESIGN §4)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from feeder.cli.arguments import add_part_arguments, add_tau_arguments, part_from, positive_float
from feeder.cli.output import print_json
from feeder.cli.waveform import file_amplifier, load_checked
from feeder.contact.breakaway import contact
from feeder.errors import InputError
from feeder.files import save_figure
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.ideal_plate import linear_flyback_step, sawtooth_motion
from feeder.plant.plant import run_waveform
from feeder.plant.stack import StackParameters
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO, Friction, StickSlip
from feeder.waveform import DIRECTIONS


def register(sub: Any) -> None:
    p = sub.add_parser("simulate", help="simulate a part stepping on the plate")
    add_part_arguments(p, example="500x500x50")
    add_tau_arguments(p, band=False)
    p.add_argument("--kinetic-ratio", type=positive_float, default=DEFAULT_KINETIC_RATIO,
                   help=f"F_k/F_s (default {DEFAULT_KINETIC_RATIO})")
    p.add_argument("--waveform", type=Path, help="waveform TOML (full plant, or --ideal)")
    p.add_argument("--periods", type=int, default=20, help="periods to simulate (default 20)")
    p.add_argument("--scatter", type=float, default=0.0,
                   help="relative step-to-step scatter of a_s (plant only, default 0)")
    p.add_argument("--seed", type=int, help="seed for --scatter")
    p.add_argument("--ideal", action="store_true",
                   help="ideal plate: follows the sawtooth exactly (no amplifier, no stack)")
    p.add_argument("--stroke-m", type=positive_float, help="ideal plate: stroke S in m")
    p.add_argument("--frequency-hz", type=positive_float, help="ideal plate: frequency")
    p.add_argument("--flyback-s", type=positive_float, help="ideal plate: flyback duration")
    p.add_argument("--flyback-shape", default="linear", choices=("linear", "half-cosine"),
                   help="ideal plate: flyback shape (default linear)")
    p.add_argument("--direction", default="forward", choices=DIRECTIONS,
                   help="ideal plate: direction (default forward)")
    p.add_argument("--plot", type=Path, metavar="PNG", help="plot part and plate position")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if args.periods < 1:
        raise InputError("--periods", f"must be at least 1, got {args.periods}")
    if not args.kinetic_ratio <= 1:
        raise InputError("--kinetic-ratio", f"must lie in (0, 1], got {args.kinetic_ratio}")
    if not (math.isfinite(args.scatter) and args.scatter >= 0):
        raise InputError("--scatter", f"must be a non-negative number, got {args.scatter}")
    part, support, surface = part_from(args)
    result = contact(part, support, surface, args.tau)
    friction = Friction(result.breakaway_accel_m_s2, args.kinetic_ratio)
    out: dict[str, Any] = {"part": part.label, "support": args.support,
                           "breakaway_accel_m_s2": friction.static_accel_m_s2,
                           "kinetic_accel_m_s2": friction.kinetic_accel_m_s2}  # fmt: skip
    if args.ideal:
        steps, slip_fraction, time, part_x, plate_x, extra = _ideal(args, friction)
    else:
        if args.waveform is None:
            raise InputError("--waveform", "required unless --ideal")
        if args.scatter > 0 and args.seed is None:
            args.seed = 0
        amplifier = file_amplifier(args.waveform)  # a design file's [amplifier], else the default
        waveform = load_checked(args.waveform, amplifier)
        if not args.json:
            print(f"simulating {args.periods} periods at 100 kS/s ...", file=sys.stderr)
        run_ = run_waveform(friction, waveform, args.periods, amplifier, scatter=args.scatter,
                            seed=args.seed)  # fmt: skip
        steps, slip_fraction = run_.steps_m, run_.slip_fraction
        time, part_x, plate_x = run_.time_s, run_.part_position_m, run_.plate_position_m
        extra = {"model": "plant", "waveform": str(args.waveform)}
    out.update(extra)
    out.update({
        "step_mean_m": float(np.mean(steps)),
        "step_std_m": float(np.std(steps, ddof=1)) if steps.size > 1 else 0.0,
        "net_displacement_m": float(np.sum(steps)),
        "periods": int(steps.size),
        "slip_fraction": slip_fraction,
        "steps_m": steps,
        "warnings": list(result.warnings),
    })
    if args.plot:
        _plot(time, part_x, plate_x, args.plot)
        out["plot"] = str(args.plot)
    if args.json:
        print_json(out)
    else:
        print(f"part {part.label} µm, a_s {friction.static_accel_m_s2:.4g} m/s², "
              f"a_k {friction.kinetic_accel_m_s2:.4g} m/s² ({out['model']})")
        print(f"  step   {out['step_mean_m'] * 1e6:.4f} ± {out['step_std_m'] * 1e6:.4f} µm "
              f"over {out['periods']} periods")
        print(f"  net    {out['net_displacement_m'] * 1e6:.4f} µm, slipping "
              f"{100 * slip_fraction:.2f} % of the time")
        if "closed_form_step_m" in out:
            print(f"  closed form {out['closed_form_step_m'] * 1e6:.6f} µm")
    return 0


def _ideal(args: argparse.Namespace, friction: Friction) -> tuple[
        np.ndarray, float, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:  # fmt: skip
    """Ideal plate from --stroke-m/--frequency-hz/--flyback-s, or from --waveform."""
    direction = args.direction
    shape = args.flyback_shape
    if args.waveform is not None:
        amplifier, stack = AmplifierLimits(), StackParameters()
        waveform = load_checked(args.waveform, amplifier)
        stroke = stack.gain_m_per_v * waveform.amplitude_vpp
        frequency, direction = waveform.frequency_hz, waveform.direction
        if waveform.flyback_shape == "current-limited":
            t_f, fraction = amplifier.current_limited_flyback(
                waveform.amplitude_vpp, frequency, stack.capacitance_f)  # fmt: skip
            flyback, stroke, shape = float(t_f), stroke * float(fraction), "linear"
        else:
            flyback, shape = waveform.command_flyback_s, waveform.flyback_shape
    else:
        for name in ("stroke_m", "frequency_hz", "flyback_s"):
            if getattr(args, name) is None:
                raise InputError(f"--{name.replace('_', '-')}", "required with --ideal (or give --waveform)")
        stroke, frequency, flyback = args.stroke_m, args.frequency_hz, args.flyback_s
        if flyback >= 1.0 / frequency:
            raise InputError(
                "--flyback-s", f"{flyback:g} s is not shorter than the period {1 / frequency:g} s"
            )
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
    extra: dict[str, Any] = {"model": "ideal", "stroke_m": stroke, "frequency_hz": frequency,
                             "flyback_s": flyback, "flyback_shape": shape, "direction": direction}
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
