"""``feeder tau``: interfacial shear strength τ = F/A_r from measured friction forces (paper Tables V–VI)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from feeder.cli.arguments import add_part_arguments, part_from, positive_float
from feeder.cli.friction import add_curve_options, analyse_files
from feeder.cli.output import print_json
from feeder.contact.asperity_sampling import DEFAULT_PLACEMENTS
from feeder.contact.breakaway import contact
from feeder.errors import InputError
from feeder.friction.shear_strength import shear_strength

BAND_NOTE = (
    "tau band = tau * sqrt((s_F/mean F)^2 + (dA/A_r)^2), s_F the sample std of the forces (ddof 1), "
    "dA/A_r the relative real-area band (--area-band; by default the half-width of the A_r interval "
    "of 68 % of random placements of the part, sampled summit by summit)"
)


def register(sub: Any) -> None:
    p = sub.add_parser("tau", help="shear strength τ = F/A_r from friction forces or force curves")
    add_part_arguments(p)
    p.add_argument("--force", action="append", required=True, metavar="N|CURVE.csv",
                   help="a static-friction force in N, or a force-curve CSV; repeat for several")
    p.add_argument("--real-area", type=positive_float,
                   help="use this real contact area in m² instead of the GW model")
    p.add_argument("--area-band", type=float,
                   help="relative half-width of the real-area band, e.g. 0.1 (default: from "
                        "placements sampled summit by summit; 0 with --real-area)")
    add_curve_options(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(handler=run)


def _forces(args: argparse.Namespace) -> tuple[list[float], list[str]]:
    """Numbers as given; file names analysed as force curves (their static-friction peak)."""
    forces: list[float] = []
    sources: list[str] = []
    for text in args.force:
        value = _number(text)
        if value is None:
            path = Path(text)
            if not path.is_file():
                raise InputError("--force", f"{text!r} is neither a force in newtons nor a force-curve file")
            ((_, peak),) = analyse_files([path], args)
            forces.append(peak.static_friction_n)
            sources.append(str(path))
            continue
        if not (math.isfinite(value) and value > 0):
            raise InputError("--force", f"must be a positive force in newtons, got {text!r}")
        forces.append(value)
        sources.append("value")
    return forces, sources


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def run(args: argparse.Namespace) -> int:
    part, support, surface = part_from(args)
    forces, sources = _forces(args)
    given_area = args.real_area is not None
    model = contact(part, support, surface, placements=0 if given_area else DEFAULT_PLACEMENTS)
    area = args.real_area if given_area else model.real_area_m2
    area_band = args.area_band
    if area_band is None:
        lo, hi = model.real_area_band_m2 or (area, area)
        area_band = (hi - lo) / (hi + lo)
    result = shear_strength(forces, area, area_band)
    checked = contact(part, support, surface, result.tau_pa, min(result.tau_band_pa, 0.999 * result.tau_pa))
    report: dict[str, Any] = {
        "tau_pa": result.tau_pa,
        "tau_band_pa": result.tau_band_pa,
        "real_area_m2": result.real_area_m2,
        "real_area_band_m2": list(result.real_area_band_m2),
        "mean_force_N": result.mean_force_n,
        "force_spread_N": result.force_spread_n,
        "inputs": {
            "part": part.label,
            "support": support.kind,
            "surface": str(args.surface) if args.surface else "embedded default",
            "forces_N": forces,
            "force_sources": sources,
            "real_area_source": "--real-area" if args.real_area is not None else "GW model",
            "area_band": area_band,
        },
        "model_real_area_m2": model.real_area_m2,
        "separation_m": model.separation_m,
        "contacts": model.contacts,
        "warnings": list(checked.warnings),
        "notes": [BAND_NOTE],
    }
    if args.json:
        print_json(report)
        return 0
    print(f"part {part.label} µm on {support.kind} support, {len(forces)} force(s), "
          f"mean {result.mean_force_n * 1e6:.4g} µN (spread {result.force_spread_n * 1e6:.3g} µN)")
    source = report["inputs"]["real_area_source"]
    print(f"real area A_r {area:.5g} m² ({source})")
    print(f"τ = {result.tau_pa / 1e9:.3f} ± {result.tau_band_pa / 1e9:.3f} GPa")
    for warning in checked.warnings:
        print(f"warning: {warning}")
    print(f"note: {BAND_NOTE}")
    return 0
