"""``feeder waveform show|export|design``: inspect a waveform file, export its tables, design one (§V.B)."""

from __future__ import annotations

import argparse
import io
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from feeder.cli.arguments import (
    add_part_arguments,
    add_tau_arguments,
    input_path,
    int_in,
    length_m,
    output_path,
    part_from,
    positive_float,
    positive_length_m,
)
from feeder.cli.output import print_json
from feeder.cli.simulate_options import plate_pose
from feeder.cli.stack_options import add_stack_arguments, stack_from
from feeder.daemon.config import PlateConfig
from feeder.errors import InputError
from feeder.files import save_figure, write_text
from feeder.plant.amplifier import AmplifierLimits, OutputStage, limits_from_table
from feeder.plant.planar_plant import DEFAULT_LEVER_ARM_M
from feeder.plant.stack import StackParameters, stack_from_table
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO
from feeder.plate_axes import AXES
from feeder.pose import MAX_POSE_M, part_pose
from feeder.waveform import (
    DEFAULT_DAC_BITS,
    DEFAULT_DAC_POINTS,
    FLYBACK_SHAPES,
    Waveform,
    load_waveform,
    read_waveform_tables,
)

if TYPE_CHECKING:
    from feeder.axis_design import AxisDesign

PLOT_SAMPLE_RATE_HZ = 100e3
MAX_DAC_POINTS = 2**20


def register(sub: Any) -> None:
    p = sub.add_parser("waveform", help="show a waveform file or export its tables")
    actions = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    show = actions.add_parser("show", help="fields, derived timing, amplifier checks")
    show.add_argument("file", type=input_path, help="waveform TOML")
    show.add_argument("--plot", type=output_path, metavar="PNG", help="plot two periods to this PNG")
    show.add_argument("--json", action="store_true", help="print one JSON object")
    show.set_defaults(handler=run)
    export = actions.add_parser("export", help="ANC300 256-point tables or a CSV DAC table")
    export.add_argument("file", type=input_path, help="waveform TOML")
    export.add_argument("--format", required=True, choices=("anc300", "csv"))
    export.add_argument(
        "--points",
        type=int_in(4, MAX_DAC_POINTS),
        default=DEFAULT_DAC_POINTS,
        help=f"CSV table length, 4–{MAX_DAC_POINTS} (default {DEFAULT_DAC_POINTS})",
    )
    export.add_argument(
        "--axis", type=int_in(1, 7), default=1, help="ANC300 axis 1–7 for setpu/setpd (default 1)"
    )
    export.add_argument("--out", type=output_path, help="write here (atomically) instead of stdout")
    export.add_argument("--json", action="store_true", help="print one JSON object")
    export.set_defaults(handler=run)
    design = actions.add_parser(
        "design", help="search the waveforms an amplifier can play for the best one (plant model)"
    )
    add_part_arguments(design, example="500x500x50")
    add_tau_arguments(design)
    design.add_argument(
        "--kinetic-ratio",
        type=positive_float,
        default=DEFAULT_KINETIC_RATIO,
        help=f"F_k/F_s (default {DEFAULT_KINETIC_RATIO})",
    )
    design.add_argument(
        "--amplifier",
        default="paper",
        help="anc300, paper (= firmware_sim, 200 V / 2 kHz) or a TOML file of "
        "amplifier limits (default paper)",
    )
    design.add_argument(
        "--objective",
        default="max-step",
        choices=("max-step", "min-scatter", "max-speed"),
        help="largest step per period, narrowest relative band, or fastest (m/s)",
    )
    design.add_argument(
        "--shapes",
        default=",".join(FLYBACK_SHAPES),
        help=f"flyback shapes to search, comma-separated (default all: {','.join(FLYBACK_SHAPES)})",
    )
    axes = design.add_mutually_exclusive_group()
    axes.add_argument(
        "--axis",
        default=None,
        choices=AXES,
        help="plate axis the design is for (default x; theta: on the planar plant at --pose)",
    )
    axes.add_argument(
        "--axes", metavar="LIST", help="several axes, e.g. x,y,theta: one file per axis, OUT-<axis>.toml"
    )
    where = design.add_mutually_exclusive_group()
    where.add_argument(
        "--pose",
        type=plate_pose,
        metavar="X,Y,PSI",
        help=f"theta: the part's pose in the plate frame, origin at O (m, m, rad; |X|, |Y| ≤ "
        f"{MAX_POSE_M:g} m, |PSI| ≤ 2π; default 0,0,0)",
    )
    where.add_argument(
        "--radius-m",
        type=length_m,
        metavar="R",
        help=f"theta: the part's distance from O, at most {MAX_POSE_M:g} m (pose R,0,0; units "
        "accepted, e.g. 1.5mm)",
    )
    design.add_argument(
        "--part-shape",
        default="rectangle",
        choices=("rectangle", "disc"),
        help="theta: footprint, rectangle LxW or disc of diameter L (default rectangle)",
    )
    design.add_argument("--lever-arm-m", type=positive_length_m, default=DEFAULT_LEVER_ARM_M, metavar="L",
                        help=f"theta: radius at which the θ stack drives the plate about O "
                             f"(default {DEFAULT_LEVER_ARM_M:g} m, firmware_sim's plate; give "
                             f"the daemon's [plate] lever_arm_m, {PlateConfig.lever_arm_m:g} m "
                             f"unless configured)")  # fmt: skip
    add_stack_arguments(design)
    design.add_argument("--out", type=output_path, required=True, help="design file (TOML) to write")
    design.add_argument("--json", action="store_true", help="print one JSON object")
    design.set_defaults(handler=run_design)


def file_amplifier(path: Path) -> AmplifierLimits:
    """The ``[amplifier]`` a design file was made for, else the default amplifier."""
    table = read_waveform_tables(path).get("amplifier")
    return AmplifierLimits() if table is None else limits_from_table(table, f"{path}: [amplifier].")


def file_stack(path: Path) -> StackParameters:
    """The ``[stack]`` a design file was made for, else the default stacks."""
    table = read_waveform_tables(path).get("stack")
    return StackParameters() if table is None else stack_from_table(table, f"{path}: [stack].")


def load_checked(path: Path, amplifier: AmplifierLimits | None = None) -> Waveform:
    """Load a waveform file and check it against the amplifier (default: the file's own, if any)."""
    waveform = load_waveform(path)
    amplifier = amplifier or file_amplifier(path)
    amplifier.check(waveform, field_prefix=f"{path}: [waveform].")
    return waveform


def run(args: argparse.Namespace) -> int:
    amplifier = file_amplifier(args.file)
    waveform = load_checked(args.file, amplifier)
    if args.action == "show":
        return _show(args, waveform, amplifier)
    return _export(args, waveform)


def _show(args: argparse.Namespace, waveform: Waveform, amplifier: AmplifierLimits) -> int:
    stack = file_stack(args.file)
    slope = amplifier.max_slope_v_per_s(stack.capacitance_f)
    fly_slope = None  # the command's steepest flyback slope: ΔV/t_f, or π·ΔV/(2 t_f) for half-cosine
    if waveform.command_flyback_s:
        peak = math.pi / 2 if waveform.flyback_shape == "half-cosine" else 1.0
        fly_slope = peak * waveform.amplitude_vpp / waveform.command_flyback_s
    # what the amplifier makes: a command it cannot follow (an instant drop, or a flyback steeper
    # than min(slew, I/C)) flies back along the current-limited ramp, as the plant simulates it
    limited = fly_slope is None or fly_slope > slope
    if limited:
        flyback, fraction = amplifier.current_limited_flyback(
            waveform.amplitude_vpp, waveform.frequency_hz, stack.capacitance_f
        )
        flyback_s, swing = float(flyback), float(fraction) * waveform.amplitude_vpp
    else:
        flyback_s, swing = waveform.command_flyback_s, waveform.amplitude_vpp
    info = {
        "file": str(args.file),
        "shape": waveform.shape,
        "frequency_hz": waveform.frequency_hz,
        "period_s": waveform.period_s,
        "amplitude_vpp": waveform.amplitude_vpp,
        "offset_v": waveform.offset_v,
        "flyback_shape": waveform.flyback_shape,
        "flyback_s": flyback_s,
        "rise_s": waveform.period_s - flyback_s,
        "direction": waveform.direction,
        "output_swing_v": swing,
        "stroke_m": swing * stack.gain_m_per_v,
        "amplifier_max_slope_v_per_s": slope,
        "command_flyback_peak_slope_v_per_s": fly_slope,
        "flyback_current_limited": limited,
        "command_flyback_s": waveform.command_flyback_s,
        "command_stroke_m": waveform.amplitude_vpp * stack.gain_m_per_v,
    }
    warnings = []
    if fly_slope is not None and fly_slope > slope:
        warnings.append(
            f"the command's flyback ({fly_slope:.3g} V/s) is faster than the amplifier can follow "
            f"({slope:.3g} V/s into {stack.capacitance_f:g} F): the current limit sets the flyback"
        )
    info["warnings"] = warnings
    if args.plot:
        _plot(waveform, amplifier, stack, args.plot)
        info["plot"] = str(args.plot)
    if args.json:
        print_json(info)
        return 0
    for key, value in info.items():
        if key == "command_flyback_peak_slope_v_per_s" and value is None:
            value = "none (the amplifier's current limit makes the flyback)"
        if key != "warnings":
            print(f"{key:<36} {value:.6g}" if isinstance(value, float) else f"{key:<36} {value}")
    for w in warnings:
        print(f"warning: {w}")
    return 0


def _export(args: argparse.Namespace, waveform: Waveform) -> int:
    if args.format == "anc300":
        up, down = waveform.anc300_tables()
        lines = [f"setpu {args.axis} " + " ".join(map(str, up)),
                 f"setpd {args.axis} " + " ".join(map(str, down))]  # fmt: skip
        text = "\n".join(lines) + "\n"
        obj: dict[str, Any] = {"format": "anc300", "points": len(up), "up": up, "down": down}
    else:
        phase = np.arange(args.points) / args.points
        shape = waveform.table(args.points)
        codes = waveform.dac_table(args.points)
        volts = waveform.voltage_at_phase(phase)
        buf = io.StringIO()
        buf.write(f"phase,shape,voltage_v,dac_code_{DEFAULT_DAC_BITS}bit\n")
        for row in zip(phase, shape, volts, codes, strict=True):
            buf.write(f"{row[0]:.9g},{row[1]:.9g},{row[2]:.9g},{int(row[3])}\n")
        text = buf.getvalue()
        obj = {"format": "csv", "points": args.points, "dac_bits": DEFAULT_DAC_BITS}
    if args.out:
        write_text(args.out, text)
        obj["path"] = str(args.out)
        if args.json:
            print_json(obj)
        return 0
    if args.json:
        if args.format == "csv":
            obj["csv"] = text
        print_json(obj)
    else:
        print(text, end="")
    return 0


def _plot(waveform: Waveform, amplifier: AmplifierLimits, stack: StackParameters, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    per = round(PLOT_SAMPLE_RATE_HZ / waveform.frequency_hz)
    index = np.arange(1, 2 * per + 1)
    command = waveform.voltage_at_phase((index % per) / per)
    output = OutputStage(amplifier, stack.capacitance_f, PLOT_SAMPLE_RATE_HZ,
                         initial_v=float(command[0])).advance(command)  # fmt: skip
    t_ms = index / PLOT_SAMPLE_RATE_HZ * 1e3
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(t_ms, command, label="command")
    ax.plot(t_ms, output, "--", label="amplifier output (limits applied)")
    ax.set_xlabel("time (ms)")
    ax.set_ylabel("voltage (V)")
    ax.set_title(f"{waveform.frequency_hz:g} Hz, {waveform.amplitude_vpp:g} Vpp, "
                 f"{waveform.flyback_shape} flyback, {waveform.direction}")  # fmt: skip
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)


def design_paths(out: Path, axes: list[str], several: bool) -> dict[str, Path]:
    """Where each axis' design goes: OUT itself, or OUT-<axis>.toml for ``--axes``."""
    if not several:
        return {axes[0]: out}
    return {axis: out.with_name(f"{out.stem}-{axis}{out.suffix or '.toml'}") for axis in axes}


def run_design(args: argparse.Namespace) -> int:
    from feeder.axis_design import AxisDesign, design_axis, write_axis_design
    from feeder.design import DesignProblem
    from feeder.plant.amplifier import resolve_amplifier

    part, support, surface = part_from(args)
    model, limits = resolve_amplifier(args.amplifier)
    shapes = tuple(s.strip() for s in args.shapes.split(",") if s.strip())
    bad = [s for s in shapes if s not in FLYBACK_SHAPES]
    if bad or not shapes:
        raise InputError("--shapes", f"expected some of {', '.join(FLYBACK_SHAPES)}, got {args.shapes!r}")
    if not args.kinetic_ratio <= 1:
        raise InputError("--kinetic-ratio", f"must lie in (0, 1], got {args.kinetic_ratio}")
    if args.axes is not None:
        axes = [a.strip() for a in args.axes.split(",") if a.strip()]
        if not axes or any(a not in AXES for a in axes) or len(set(axes)) != len(axes):
            raise InputError("--axes", f"expected distinct axes among {','.join(AXES)}, got {args.axes!r}")
    else:
        axes = [args.axis or "x"]
    if "theta" in axes and args.objective == "min-scatter":
        raise InputError("--objective", "theta designs max-step or max-speed (min-scatter is for x and y)")
    if args.radius_m is not None and args.radius_m < 0:
        raise InputError("--radius-m", f"must not be negative, got {args.radius_m}")
    if args.radius_m is not None:  # the pose R,0,0, checked as --pose is
        part_pose((args.radius_m, 0.0, 0.0), "--radius-m", f"R = {args.radius_m:g} m (the pose R,0,0)")
    where = args.pose or ((args.radius_m, 0.0, 0.0) if args.radius_m is not None else (0.0, 0.0, 0.0))
    problem = DesignProblem(part, support, surface, str(args.surface or "embedded"), args.tau,
                            args.tau_band, args.kinetic_ratio, model, limits, stack_from(args),
                            tau_adhesion_work_j_m2=args.tau_adhesion_work)  # fmt: skip

    def progress(message: str) -> None:
        print(f"design: {message}", file=sys.stderr, flush=True)

    paths = design_paths(args.out, axes, args.axes is not None)
    designs: dict[str, AxisDesign] = {}
    for axis in axes:
        translation = next((d for d in designs.values() if d.axis != "theta"), None)
        if axis != "theta" and translation is not None:  # x and y: the same 1-D design (DESIGN §9)
            designs[axis] = AxisDesign(axis, translation.design, where, args.lever_arm_m, args.part_shape)
        else:
            designs[axis] = design_axis(problem, axis, args.objective, pose=where,
                                        lever_arm_m=args.lever_arm_m, part_shape=args.part_shape,
                                        shapes=shapes, progress=progress)  # fmt: skip
    for axis, design in designs.items():  # written once all are found: nothing half-done on an error
        write_axis_design(paths[axis], problem, design, written_by="feeder waveform design")
    head = {"part": part.label, "support": support.kind, "amplifier": model}
    if args.axes is None:
        out = {**head, **designs[axes[0]].to_json(), "path": str(args.out)}
    else:
        each = {a: {**d.to_json(), "path": str(paths[a])} for a, d in designs.items()}
        out = {**head, "axes": axes, "designs": each}
    if args.json:
        print_json(out)
        return 0
    for axis, axis_design in designs.items():
        _print_design(args, part.label, support.kind, model, axis_design, paths[axis])
    return 0


def _print_design(args: argparse.Namespace, part: str, support: str, model: str, axis_design: AxisDesign,
                  path: Path) -> None:  # fmt: skip
    design = axis_design.design
    w, (lo, hi) = design.waveform, design.predicted_step_band_m
    flyback = f"{w.flyback_s * 1e6:.4g} µs " if w.flyback_s else ""
    print(
        f"design for part {part} µm on {support} support, amplifier {model}, "
        f"objective {args.objective}, axis {axis_design.axis}: {path}"
    )
    print(
        f"  waveform   {w.frequency_hz:.5g} Hz, {w.amplitude_vpp:.5g} Vpp, {flyback}{w.flyback_shape} flyback"
    )
    if axis_design.turn_rad is not None and axis_design.turn_band_rad is not None:
        t_lo, t_hi = axis_design.turn_band_rad
        print(
            f"  turn       {axis_design.turn_rad * 1e3:.4g} mrad  [{t_lo * 1e3:.4g}, {t_hi * 1e3:.4g}] "
            f"per period at {axis_design.radius_m * 1e3:.4g} mm from O (planar plant)"
        )
    print(
        f"  step       {design.predicted_step_m * 1e6:.4g} µm  [{lo * 1e6:.4g}, {hi * 1e6:.4g}], "
        f"{design.speed_m_s * 1e3:.4g} mm/s"
    )
    m = design.margins
    print(
        f"  margins    flyback {m['flyback_margin']:.3g}×, ramp {m['ramp_margin']:.3g}×, "
        f"rail {m['rail_margin_v']:.3g} V, current {m['current_margin']:.3g}×"
    )
