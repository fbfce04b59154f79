"""``feeder friction``: static-friction peaks of AFM force curves, mean and spread (paper §V.A)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from feeder.cli.arguments import float_in, input_path, output_path
from feeder.cli.output import print_json
from feeder.errors import InputError
from feeder.files import save_figure
from feeder.friction.cantilevers import CANTILEVERS, cantilever_stiffness
from feeder.friction.force_curves import (
    ForceCurve,
    FrictionPeak,
    analyse_force_curve,
    read_force_curve,
    summarize,
)


def add_curve_options(p: argparse.ArgumentParser) -> None:
    """Cantilever and analysis options shared with ``feeder tau``."""
    p.add_argument("--cantilever", help=f"preset for deflection curves: {', '.join(CANTILEVERS)}")
    p.add_argument(
        "--stiffness",
        type=float_in(1e-4, 1e4),
        help="cantilever stiffness in N/m, 1e-4–1e4 (wins over presets)",
    )
    p.add_argument(
        "--baseline-fraction",
        type=float,
        default=0.2,
        help="leading fraction of samples taken as free-approach baseline (default 0.2)",
    )


def analyse_files(paths: list[Path], args: argparse.Namespace) -> list[tuple[ForceCurve, FrictionPeak]]:
    """Read and analyse force-curve files with the shared options."""
    stiffness = cantilever_stiffness(args.cantilever, args.stiffness)
    curves = [read_force_curve(p, stiffness) for p in paths]
    return [(c, analyse_force_curve(c, args.baseline_fraction)) for c in curves]


def register(sub: Any) -> None:
    p = sub.add_parser("friction", help="static-friction peaks of force curves (CSV)")
    p.add_argument(
        "curves",
        nargs="+",
        type=input_path,
        metavar="CURVE.csv",
        help="force curves: displacement_m and deflection_m or force_n columns",
    )
    add_curve_options(p)
    p.add_argument("--plot", type=output_path, help="PNG of the curves with onset, peak and sliding level")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if args.plot is not None and (args.plot.is_dir() or not args.plot.parent.is_dir()):
        raise InputError("--plot", f"cannot write {args.plot}: a directory, or its directory does not exist")
    analysed = analyse_files(args.curves, args)
    summary = summarize([peak for _, peak in analysed])
    report: dict[str, Any] = {
        "count": summary.count,
        "mean_static_friction_N": summary.mean_static_friction_n,
        "static_friction_std_N": summary.static_friction_std_n,
        "static_friction_sem_N": summary.static_friction_sem_n,
        "min_static_friction_N": summary.min_static_friction_n,
        "max_static_friction_N": summary.max_static_friction_n,
        "mean_sliding_force_N": summary.mean_sliding_force_n,
        "curves": [_curve_json(curve, peak) for curve, peak in analysed],
        "warnings": [w for curve, _ in analysed for w in curve.warnings],
    }
    if args.plot is not None:
        _plot(analysed, args.plot)
        report["plot"] = str(args.plot)
    if args.json:
        print_json(report)
        return 0
    for item in report["curves"]:
        print(
            f"{item['file']}: static friction {item['static_friction_N'] * 1e6:.4g} µN at "
            f"{item['peak_displacement_m'] * 1e6:.4g} µm "
            f"(contact at {item['contact_onset_m'] * 1e6:.4g} µm), "
            f"sliding {item['sliding_force_N'] * 1e6:.4g} ± {item['sliding_force_std_N'] * 1e6:.2g} µN, "
            f"noise {item['noise_N'] * 1e9:.3g} nN"
        )
    spread = f" ± {summary.static_friction_std_n * 1e6:.3g} (std)" if summary.count > 1 else ""
    print(
        f"mean static friction of {summary.count} curve(s): "
        f"{summary.mean_static_friction_n * 1e6:.4g}{spread} µN"
    )
    for warning in report["warnings"]:
        print(f"warning: {warning}")
    if args.plot is not None:
        print(f"wrote {args.plot}")
    return 0


def _curve_json(curve: ForceCurve, peak: FrictionPeak) -> dict[str, Any]:
    return {
        "file": peak.source,
        "stiffness_N_per_m": curve.stiffness_n_per_m,
        "static_friction_N": peak.static_friction_n,
        "peak_displacement_m": peak.peak_displacement_m,
        "contact_onset_m": peak.contact_onset_m,
        "sliding_force_N": peak.sliding_force_n,
        "sliding_force_std_N": peak.sliding_force_std_n,
        "kinetic_to_static_ratio": peak.sliding_force_n / peak.static_friction_n,
        "noise_N": peak.noise_n,
        "baseline_offset_N": peak.baseline_offset_n,
    }


def _plot(analysed: list[tuple[ForceCurve, FrictionPeak]], path: Path) -> None:
    """Force vs support displacement (baseline removed), like the paper's Figs. 10 and 11."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for curve, peak in analysed:
        x_um = curve.displacement_m * 1e6
        (line,) = ax.plot(
            x_um,
            peak.corrected_force_n(curve) * 1e6,
            lw=0.7,
            label=f"{Path(peak.source).name}: {peak.static_friction_n * 1e6:.4g} µN",
        )
        colour = line.get_color()
        ax.plot(peak.peak_displacement_m * 1e6, peak.static_friction_n * 1e6, "v", color=colour, ms=7)
        ax.axvline(peak.contact_onset_m * 1e6, color=colour, ls=":", lw=0.8)
        ax.hlines(
            peak.sliding_force_n * 1e6,
            x_um[peak.slip_index],
            x_um[-1],
            colors=colour,
            linestyles="--",
            lw=0.8,
        )
    ax.set_xlabel("support displacement (µm)")
    ax.set_ylabel("friction force (µN)")
    ax.set_title(
        "force curves: contact onset (dotted), static-friction peak (▼), sliding level (dashed)", fontsize=8
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
