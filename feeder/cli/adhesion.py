"""``feeder adhesion sphere``: one sphere on a flat with Hertz, DMT, JKR or Maugis–Dugdale (DESIGN §11)."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path
from typing import Any

from feeder.cli.arguments import (
    add_part_arguments,
    adhesion_work,
    float_in,
    output_path,
    part_from,
    positive_float,
)
from feeder.cli.output import print_json
from feeder.contact.adhesion_fit import RATIO_BAND, AdhesionFit, check_ratios, default_band, fit_adhesion_work
from feeder.contact.adhesion_sphere import DEFAULT_RANGE_M, MODELS, SphereContact
from feeder.contact.tau_pair import fitted_tau
from feeder.errors import InputError
from feeder.files import save_figure
from feeder.paper import GROOVED_FRICTION_RATIO
from feeder.surface.parameters import ADHESION_WORK_HELP

CURVE_POINTS = 200


def register(sub: Any) -> None:
    p = sub.add_parser("adhesion", help="single-asperity adhesion: Hertz, DMT, JKR, Maugis–Dugdale")
    kinds = p.add_subparsers(dest="geometry", required=True, parser_class=type(p))
    s = kinds.add_parser("sphere", help="a sphere on a flat")
    s.add_argument(
        "--radius",
        type=float_in(1e-10, 1.0),
        required=True,
        metavar="M",
        help="sphere radius R in m, 0.1 nm–1 m",
    )
    s.add_argument(
        "--modulus",
        type=float_in(1e3, 1e13),
        required=True,
        metavar="PA",
        help="reduced modulus E* in Pa, 1 kPa–10 TPa (1/E* = (1−ν1²)/E1 + (1−ν2²)/E2)",
    )
    s.add_argument(
        "--adhesion-work",
        type=adhesion_work,
        required=True,
        metavar="J_M2",
        help=f"work of adhesion w, {ADHESION_WORK_HELP}",
    )
    scale = s.add_mutually_exclusive_group()
    scale.add_argument(
        "--tabor",
        type=float_in(1e-3, 1e3),
        metavar="L",
        help="0.001–1000: Maugis' λ = 2σ₀(R/(πwK²))^(1/3), K = 4E*/3 (not Tabor's μ ≈ λ/1.16)",
    )
    scale.add_argument(
        "--range",
        type=float_in(1e-12, 1e-6),
        metavar="M",
        help=f"Dugdale range h₀ = w/σ₀ in m, 1 pm–1 µm (default {DEFAULT_RANGE_M:g} = 0.971 z₀)",
    )
    s.add_argument("--model", choices=MODELS, default="maugis-dugdale", help="default maugis-dugdale")
    what = s.add_mutually_exclusive_group()
    what.add_argument(
        "--load",
        type=float_in(-1e6, 1e6),
        metavar="N",
        help="contact radius and approach at this load (|load| ≤ 1e6 N)",
    )
    what.add_argument("--curve", action="store_true", help="the load–radius–approach curve")
    s.add_argument(
        "--max-load",
        type=float_in(1e-15, 1e6),
        metavar="N",
        help="top of --curve, 1e-15–1e6 N (default 10 πwR)",
    )
    s.add_argument("--plot", type=output_path, metavar="PNG", help="plot the curve (implies --curve)")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.set_defaults(handler=run)
    f = kinds.add_parser("fit", help="the w that gives the measured grooved/flat ratio (GW-MD)")
    add_part_arguments(f, part_required=False)
    f.add_argument(
        "--ratio",
        type=positive_float,
        default=GROOVED_FRICTION_RATIO,
        help=f"target grooved/flat ratio, in (0, 1] (default the measured {GROOVED_FRICTION_RATIO}); "
        "one the model does not reach is refused (exit 1)",
    )
    f.add_argument(
        "--ratio-band",
        type=positive_float,
        nargs=2,
        metavar=("LO", "HI"),
        help=f"ratio band mapped to a w band, LO < HI in (0, 1] around --ratio (default the "
        f"measured {RATIO_BAND[0]} {RATIO_BAND[1]}; ± {(RATIO_BAND[1] - RATIO_BAND[0]) / 2:g} around "
        "another --ratio)",
    )
    f.add_argument("--plot", type=output_path, metavar="PNG", help="ratio against w")
    f.add_argument("--json", action="store_true", help="print one JSON object")
    f.set_defaults(handler=run_fit, part="300x300x50")


def run(args: argparse.Namespace) -> int:
    if args.plot is not None and (args.plot.is_dir() or not args.plot.parent.is_dir()):
        raise InputError("--plot", f"cannot write {args.plot}: a directory, or its directory does not exist")
    if args.tabor is not None:
        sphere = SphereContact(args.radius, args.modulus, args.adhesion_work, args.tabor)
        source = "--tabor"
    else:
        sphere = SphereContact.from_range(
            args.radius,
            args.modulus,
            args.adhesion_work,
            DEFAULT_RANGE_M if args.range is None else args.range,
        )
        source = "--range" if args.range is not None else f"default range {DEFAULT_RANGE_M:g} m"
    adhesive = sphere.adhesion_work_j_m2 > 0
    report: dict[str, Any] = {
        "model": args.model,
        "radius_m": sphere.radius_m,
        "modulus_pa": sphere.modulus_pa,
        "adhesion_work_j_m2": sphere.adhesion_work_j_m2,
        "tabor": sphere.tabor if adhesive else None,
        "tabor_source": source if adhesive else None,
        "dugdale_stress_pa": sphere.dugdale_stress_pa if adhesive else None,
        "dugdale_range_m": sphere.dugdale_range_m if adhesive else None,
        "pull_off_n": sphere.pull_off_n(args.model),
    }
    if args.load is not None:
        radius, approach = sphere.state_at_load(args.model, args.load)
        report.update(load_n=args.load, contact_radius_m=radius, approach_m=approach)
    if args.curve or args.plot is not None:
        top: float | None = args.max_load
        if top is None:
            if not adhesive:
                raise InputError("--max-load", "needed for a curve without adhesion (w = 0)")
            top = 10.0 * sphere.load_unit_n
        loads, radii, approaches = sphere.curve(args.model, float(top), CURVE_POINTS)
        report["curve"] = {"load_n": loads, "contact_radius_m": radii, "approach_m": approaches}
        if args.plot is not None:
            _plot(sphere, args.model, loads, radii, approaches, args.plot)
            report["plot"] = str(args.plot)
    if args.json:
        print_json(report)
        return 0
    print(
        f"{args.model}: R {sphere.radius_m:g} m, E* {sphere.modulus_pa:g} Pa, "
        f"w {sphere.adhesion_work_j_m2:g} J/m²"
    )
    if adhesive:
        print(
            f"  Maugis λ {sphere.tabor:.4g} ({source}), σ₀ {sphere.dugdale_stress_pa:.4g} Pa, "
            f"h₀ {sphere.dugdale_range_m:.4g} m"
        )
    print(f"  pull-off {report['pull_off_n']:.6g} N")
    if args.load is not None:
        print(
            f"  at {args.load:g} N: contact radius {report['contact_radius_m']:.6g} m, "
            f"approach {report['approach_m']:.6g} m"
        )
    if "plot" in report:
        print(f"wrote {report['plot']}")
    return 0


def _plot(sphere: SphereContact, model: str, load: Any, radius: Any, approach: Any, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    left.plot(load * 1e9, radius * 1e9)
    left.set_xlabel("load (nN)")
    left.set_ylabel("contact radius (nm)")
    right.plot(approach * 1e9, load * 1e9)
    right.set_xlabel("approach (nm)")
    right.set_ylabel("load (nN)")
    pull = sphere.pull_off_n(model)
    for ax in (left, right):
        ax.grid(alpha=0.3)
        if pull > 0 and math.isfinite(pull):
            (ax.axvline if ax is left else ax.axhline)(
                -pull * 1e9, color="r", ls="--", lw=0.8, label=f"pull-off {pull * 1e9:.3g} nN"
            )
            ax.legend(fontsize=8)
    fig.suptitle(
        f"{model}, R = {sphere.radius_m * 1e9:g} nm, w = {sphere.adhesion_work_j_m2:g} J/m²"
        + (f", λ = {sphere.tabor:.3g}" if model == "maugis-dugdale" else ""),
        fontsize=10,
    )
    fig.tight_layout()
    save_figure(fig, path)


def run_fit(args: argparse.Namespace) -> int:
    if args.plot is not None and (args.plot.is_dir() or not args.plot.parent.is_dir()):
        raise InputError("--plot", f"cannot write {args.plot}: a directory, or its directory does not exist")
    band = default_band(args.ratio) if args.ratio_band is None else (args.ratio_band[0], args.ratio_band[1])
    try:
        check_ratios(args.ratio, band)
    except InputError as err:
        raise InputError("--ratio" if err.field == "target" else "--ratio-band", err.message) from None
    part, _, surface = part_from(args)
    fit = fit_adhesion_work(surface, part, args.ratio, band)
    if fit.adhesion_work_j_m2 is None:  # a ratio the model cannot give: refused, nothing written
        print(f"feeder adhesion: refused: {fit.explanation}", file=sys.stderr)
        return 1
    report: dict[str, Any] = {
        "part": part.label,
        "target_ratio": fit.target_ratio,
        "ratio_band": list(band),
        "adhesion_work_j_m2": fit.adhesion_work_j_m2,
        "ratio_slope_per_j_m2": fit.ratio_slope_per_j_m2,
        "adhesion_work_band_j_m2": fit.adhesion_work_band_j_m2,
        "ratio_range": list(fit.ratio_range),
        "curve": {"adhesion_work_j_m2": fit.curve_w_j_m2, "ratio": fit.curve_ratio},
        "explanation": fit.explanation,
    }
    pair = fitted_tau(dataclasses.replace(surface, adhesion_work_j_m2=fit.adhesion_work_j_m2))
    report.update(tau_pa=pair.tau_pa, tau_band_pa=pair.tau_band_pa)
    if args.plot is not None:
        _plot_fit(fit, args.plot)
        report["plot"] = str(args.plot)
    if args.json:
        print_json(report)
        return 0
    print(fit.explanation)
    if fit.adhesion_work_band_j_m2 is not None:
        lo, hi = fit.adhesion_work_band_j_m2
        print(f"  ratio band {band[0]:g}–{band[1]:g} → w {lo:.4g}–{hi:.4g} J/m²")
    print(f"  τ fitted with that w: {report['tau_pa']:.4g} ± {report['tau_band_pa']:.3g} Pa")
    return 0


def _plot_fit(fit: AdhesionFit, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogx(fit.curve_w_j_m2, fit.curve_ratio, "o-", label="GW-MD model")
    ax.axhline(fit.target_ratio, color="r", ls="--", lw=0.8, label=f"measured {fit.target_ratio:g}")
    if fit.adhesion_work_j_m2 is not None:
        ax.axvline(
            fit.adhesion_work_j_m2, color="k", ls=":", lw=0.8, label=f"w = {fit.adhesion_work_j_m2:.3g} J/m²"
        )
    ax.set_xlabel("work of adhesion w (J/m²)")
    ax.set_ylabel("A_r grooved / A_r flat")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)
