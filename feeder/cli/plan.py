"""``feeder plan``: waveform, step count and predicted step ± band for a wanted displacement."""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import Any

from feeder.cli.arguments import (
    add_part_arguments,
    add_tau_arguments,
    float_in,
    length_in,
    output_path,
    part_from,
    positive_float,
)
from feeder.cli.output import print_json
from feeder.cli.stack_options import add_stack_arguments, stack_from
from feeder.planner import DEFAULT_MARGIN, StepPrediction, plan
from feeder.plant.amplifier import AmplifierLimits, resolve_amplifier
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO

_DEFAULT_AMPLIFIER = AmplifierLimits()


def register(sub: Any) -> None:
    p = sub.add_parser("plan", help="plan a move: waveform, steps, predicted step and band")
    add_part_arguments(p)
    p.add_argument(
        "--distance-m",
        type=length_in(-1.0, 1.0),
        required=True,
        help="wanted displacement in m (or with a unit: 100um), at most 1 m either way; negative: "
        "backward (e.g. -20e-6)",
    )
    add_tau_arguments(p)
    p.add_argument(
        "--kinetic-ratio",
        type=positive_float,
        default=DEFAULT_KINETIC_RATIO,
        help=f"F_k/F_s, in (0, 1] (default {DEFAULT_KINETIC_RATIO})",
    )
    p.add_argument(
        "--margin",
        type=positive_float,
        default=DEFAULT_MARGIN,
        help=f"k in the acceleration margins, ≥ 1 (default {DEFAULT_MARGIN})",
    )
    p.add_argument(
        "--frequency-hz", type=float_in(1e-3, 1e6), help="fix the frequency, 1 mHz–1 MHz (default: chosen)"
    )
    p.add_argument(
        "--amplifier",
        default=None,
        help="amplifier model (anc300, paper = firmware_sim) or a TOML file of its limits; "
        "the three options below override its values (default: firmware_sim)",
    )
    p.add_argument(
        "--max-voltage-v",
        type=float_in(1e-3, 1e4),
        help=f"amplifier rail, 1 mV–10 kV (default {_DEFAULT_AMPLIFIER.v_max_v:g} V)",
    )
    p.add_argument(
        "--current-limit-a",
        type=float_in(1e-6, 1e3),
        help=f"amplifier peak current, 1 µA–1 kA (default {_DEFAULT_AMPLIFIER.current_limit_a:g} A)",
    )
    p.add_argument(
        "--max-frequency-hz",
        type=float_in(1e-3, 1e6),
        help=f"amplifier's highest frequency, 1 mHz–1 MHz "
        f"(default {_DEFAULT_AMPLIFIER.max_frequency_hz:g} Hz)",
    )
    add_stack_arguments(p)
    p.add_argument(
        "--out",
        type=output_path,
        metavar="TOML",
        help="write the waveform with the prediction it was planned with (a design file)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    part, support, surface = part_from(args)
    model, amplifier = (
        resolve_amplifier(args.amplifier) if args.amplifier else ("firmware_sim", _DEFAULT_AMPLIFIER)
    )
    overrides = {name: value for name, value in (("v_max_v", args.max_voltage_v),
                 ("current_limit_a", args.current_limit_a), ("max_frequency_hz", args.max_frequency_hz))
                 if value is not None}  # fmt: skip
    if overrides:
        model, amplifier = f"{model} (modified)", replace(amplifier, **overrides)
    stack = stack_from(args)
    result = plan(part, support, surface, args.tau, amplifier, args.distance_m,
                  tau_band_pa=args.tau_band, kinetic_ratio=args.kinetic_ratio,
                  tau_adhesion_work_j_m2=args.tau_adhesion_work, stack=stack, margin=args.margin,
                  frequency_hz=args.frequency_hz)  # fmt: skip
    out = {"part": part.label, "support": support.kind, **result.to_json()}
    if args.out:
        from feeder.design import DesignProblem, write_design

        problem = DesignProblem(part, support, surface, str(args.surface or "embedded"), args.tau,
                                args.tau_band, args.kinetic_ratio, model, amplifier, stack,
                                tau_adhesion_work_j_m2=args.tau_adhesion_work)  # fmt: skip
        prediction = StepPrediction(result.predicted_step_m, result.predicted_step_band_m)
        moves = {"distance_m": result.distance_m, "steps": result.steps, "duration_s": result.duration_s,
                 "predicted_distance_m": result.predicted_distance_m,
                 "predicted_distance_band_m": list(result.predicted_distance_band_m)}  # fmt: skip
        write_design(
            args.out,
            problem,
            result.waveform(),
            prediction,
            {"plan": moves, "margins": dict(result.margins)},
            written_by="feeder plan",
        )
        out["path"] = str(args.out)
    if args.json:
        print_json(out)
        return 0
    lo, hi = result.predicted_step_band_m
    print(f"move {args.distance_m * 1e6:.4g} µm: part {part.label} µm on {support.kind} support")
    print(
        f"  waveform   {result.frequency_hz:.4g} Hz, {result.amplitude_vpp:.4g} Vpp, "
        f"{result.flyback_shape} flyback {result.flyback_s * 1e6:.4g} µs, {result.direction}"
    )
    print(f"  steps      {result.steps}, {result.duration_s:.4g} s")
    print(f"  step       {result.predicted_step_m * 1e6:.4g} µm  [{lo * 1e6:.4g}, {hi * 1e6:.4g}]")
    print(f"  a_break    {result.breakaway_accel_m_s2:.4g} m/s²")
    m = result.margins
    print(
        f"  margins    flyback {m['flyback_margin']:.3g}×, ramp {m['ramp_margin']:.3g}× "
        f"(required {m['required']:g}×)"
    )
    for w in result.warnings:
        print(f"  warning: {w}")
    if args.out:
        print(f"  written    {args.out}")
    return 0
