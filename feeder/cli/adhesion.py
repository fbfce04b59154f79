"""``feeder adhesion sphere``: one sphere on a flat with Hertz, DMT, JKR or Maugis–Dugdale (DESIGN §11)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from feeder.cli.arguments import positive_float
from feeder.cli.output import print_json
from feeder.contact.adhesion_sphere import DEFAULT_RANGE_M, MODELS, SphereContact
from feeder.errors import InputError
from feeder.files import save_figure

CURVE_POINTS = 200


def register(sub: Any) -> None:
    p = sub.add_parser("adhesion", help="single-asperity adhesion: Hertz, DMT, JKR, Maugis–Dugdale")
    kinds = p.add_subparsers(dest="geometry", required=True, parser_class=type(p))
    s = kinds.add_parser("sphere", help="a sphere on a flat")
    s.add_argument("--radius", type=positive_float, required=True, metavar="M", help="sphere radius R in m")
    s.add_argument(
        "--modulus",
        type=positive_float,
        required=True,
        metavar="PA",
        help="reduced modulus E* in Pa (1/E* = (1−ν1²)/E1 + (1−ν2²)/E2)",
    )
    s.add_argument("--adhesion-work", type=float, required=True, metavar="J_M2", help="work of adhesion w")
    scale = s.add_mutually_exclusive_group()
    scale.add_argument(
        "--tabor",
        type=float,
        metavar="L",
        help="Maugis' λ = 2σ₀(R/(πwK²))^(1/3), K = 4E*/3 (not Tabor's μ ≈ λ/1.16)",
    )
    scale.add_argument(
        "--range",
        type=float,
        metavar="M",
        help=f"Dugdale range h₀ = w/σ₀ in m (default {DEFAULT_RANGE_M:g} = 0.971 z₀)",
    )
    s.add_argument("--model", choices=MODELS, default="maugis-dugdale", help="default maugis-dugdale")
    what = s.add_mutually_exclusive_group()
    what.add_argument("--load", type=float, metavar="N", help="contact radius and approach at this load")
    what.add_argument("--curve", action="store_true", help="the load–radius–approach curve")
    s.add_argument("--max-load", type=positive_float, metavar="N", help="top of --curve (default 10 πwR)")
    s.add_argument("--plot", type=Path, metavar="PNG", help="plot the curve (implies --curve)")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.set_defaults(handler=run)


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
