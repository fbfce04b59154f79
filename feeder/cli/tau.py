"""``feeder tau``: interfacial shear strength τ = F/A_r from measured friction forces (paper Tables V–VI)."""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

from feeder.cli.arguments import add_part_arguments, part_from, positive_float
from feeder.cli.friction import add_curve_options, analyse_files
from feeder.cli.output import print_json
from feeder.contact.breakaway import contact
from feeder.contact.resting_part import DEFAULT_PLACEMENTS
from feeder.contact.tau_pair import ADHESION_WORK_REL_BAND
from feeder.errors import InputError
from feeder.friction.shear_strength import shear_strength
from feeder.paper import TAU_MEAN_PA, TAU_SPREAD_PA

BAND_NOTE = (
    "tau band = tau * sqrt(scatter^2 + (dA/A_r)^2), each source counted once: scatter = s_F/mean F "
    "(sample std, ddof 1) of two or more forces, which already holds the placement-to-placement "
    "scatter of A_r (every measurement is a placement); for one force, the predicted scatter of one "
    "placement (68 % interval of placements of the rigid part at rest, tilted, w = 0) or the paper's "
    "relative spread 3.15/22.18 (w > 0). dA/A_r = the model's real-area uncertainty: the half-width "
    "of A_r over the w band (--adhesion-work-band, default ±8.64 % of w, the band that maps the measured "
    "grooved/flat ratio 0.70-0.78), or --area-band; 0 with --real-area and no --area-band"
)

FORCE_WEIGHT_RATIO_WARNING = 1e4
"""Warn when a force exceeds this many times the part's weight (the paper's: 7–15×)."""


def register(sub: Any) -> None:
    p = sub.add_parser("tau", help="shear strength τ = F/A_r from friction forces or force curves")
    add_part_arguments(p)
    p.add_argument(
        "--force",
        action="append",
        required=True,
        metavar="N|CURVE.csv",
        help="a static-friction force in N (25 µN is 25e-6), or a force-curve CSV; repeat for several",
    )
    p.add_argument(
        "--real-area", type=positive_float, help="use this real contact area in m² instead of the GW model"
    )
    p.add_argument(
        "--area-band",
        type=float,
        help="relative half-width of the model's real-area band, e.g. 0.1 (default: A_r over "
        "the w band; 0 with --real-area)",
    )
    p.add_argument(
        "--adhesion-work-band",
        type=float,
        metavar="J_M2",
        help=f"± uncertainty of --adhesion-work (default {ADHESION_WORK_REL_BAND:g} w)",
    )
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


def _force_warnings(forces: list[float], sources: list[str], weight_n: float) -> list[str]:
    """A force far above the part's weight: most likely µN typed as N (--force takes newtons)."""
    out = []
    for force, source in zip(forces, sources, strict=True):
        ratio = force / weight_n
        if ratio > FORCE_WEIGHT_RATIO_WARNING:
            given = f"--force {force:.4g} N" if source == "value" else f"--force {source} ({force:.4g} N)"
            out.append(
                f"{given} is {ratio:.3g}× the part's weight ({weight_n:.3g} N): wrong unit? --force "
                "takes newtons (25 µN is 25e-6); the paper's forces are 7–15× the weight, and friction "
                "this far above it needs adhesion-dominated micro-parts"
            )
    return out


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def run(args: argparse.Namespace) -> int:
    part, support, surface = part_from(args)
    forces, sources = _forces(args)
    given_area = args.real_area is not None
    w = surface.adhesion_work_j_m2
    model = contact(part, support, surface, placements=0 if given_area or w else DEFAULT_PLACEMENTS)
    area = args.real_area if given_area else model.real_area_m2
    w_band = ADHESION_WORK_REL_BAND * w if args.adhesion_work_band is None else args.adhesion_work_band
    if not (math.isfinite(w_band) and (w_band == 0 or 0 < w_band < w)):
        raise InputError("--adhesion-work-band", f"must be ≥ 0 and below w, got {w_band!r}")
    area_ends = (area, area)
    if not given_area and w_band > 0:
        area_ends = tuple(  # type: ignore[assignment]
            contact(part, support, replace(surface, adhesion_work_j_m2=w + sign * w_band)).real_area_m2
            for sign in (-1.0, 1.0)
        )
    area_band = args.area_band
    if area_band is None:
        area_band = 0.0 if given_area else abs(area_ends[1] - area_ends[0]) / (area_ends[1] + area_ends[0])
    scatter_source = "force spread"
    single_scatter = 0.0
    if len(forces) == 1 and not given_area:
        if model.real_area_band_m2 is not None:
            lo, hi = model.real_area_band_m2
            single_scatter, scatter_source = (hi - lo) / (hi + lo), "placement sampling"
        else:
            single_scatter, scatter_source = TAU_SPREAD_PA / TAU_MEAN_PA, "paper's relative spread"
    result = shear_strength(forces, area, area_band, single_scatter)
    warnings = _force_warnings(forces, sources, part.weight_n)
    checked = contact(
        part,
        support,
        surface,
        result.tau_pa,
        min(result.tau_band_pa, 0.999 * result.tau_pa),
        tau_adhesion_work_j_m2=w,
    )
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
            "adhesion_work_j_m2": w,
            "adhesion_work_band_j_m2": w_band,
            "scatter_source": scatter_source,
        },
        "tau_adhesion_work_j_m2": w,
        "model_real_area_m2": model.real_area_m2,
        "separation_m": model.separation_m,
        "contacts": model.contacts,
        "warnings": warnings + list(checked.warnings),
        "notes": [BAND_NOTE],
    }
    if args.json:
        print_json(report)
        return 0
    print(
        f"part {part.label} µm on {support.kind} support, {len(forces)} force(s), "
        f"mean {result.mean_force_n * 1e6:.4g} µN (spread {result.force_spread_n * 1e6:.3g} µN)"
    )
    source = report["inputs"]["real_area_source"]
    print(f"real area A_r {area:.5g} m² ({source})")
    print(f"τ = {result.tau_pa / 1e9:.3f} ± {result.tau_band_pa / 1e9:.3f} GPa")
    for warning in report["warnings"]:
        print(f"warning: {warning}")
    print(f"note: {BAND_NOTE}")
    return 0
