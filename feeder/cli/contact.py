"""``feeder contact``: separation, real area and breakaway force of a part (paper §III)."""

from __future__ import annotations

import argparse
from typing import Any

from feeder.cli.arguments import (
    add_part_arguments,
    add_tau_arguments,
    int_in,
    materials_from,
    part_from,
    surface_from,
)
from feeder.cli.output import print_json
from feeder.contact.breakaway import MIN_CONTACTS, ContactResult, contact
from feeder.contact.resting_part import DEFAULT_PLACEMENTS
from feeder.errors import InputError
from feeder.paper import PAPER_ROWS
from feeder.parts import Part, Support
from feeder.surface.parameters import SurfaceParameters


def register(sub: Any) -> None:
    p = sub.add_parser("contact", help="real contact area and breakaway force of a part")
    add_part_arguments(p, part_required=False)
    p.set_defaults(support=None)  # None: not given (--table refuses it); flat otherwise
    add_tau_arguments(p)
    p.add_argument(
        "--placements",
        type=int_in(0, 10**6),
        default=DEFAULT_PLACEMENTS,
        help="random placements of the rigid part, each at rest on ≥ 3 summits (tilted), for the "
        "A_r band, 0–1e6 "
        f"(default {DEFAULT_PLACEMENTS}; 0 skips; within the 2 GiB memory budget)",
    )
    p.add_argument(
        "--table",
        action="store_true",
        help="paper-style table: the paper's four silicon parts × two supports, model vs paper "
        "(takes no --part, --support or --density)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if not 0 <= args.placements <= 1_000_000:
        raise InputError("--placements", f"must be between 0 and 1000000, got {args.placements}")
    if args.table:
        for option in ("part", "support", "density"):
            if getattr(args, option) is not None:
                rows = "its rows are the paper's four silicon parts on both supports"
                raise InputError(f"--{option}", f"not with --table ({rows})")
        return _table(surface_from(args), args, args.placements, args.json)
    if not args.part:
        raise InputError("--part", "required (LxWxT in µm, e.g. 300x300x50), or use --table")
    if args.support is None:
        args.support = "flat"
    part, support, surface = part_from(args)
    result = contact(
        part,
        support,
        surface,
        args.tau,
        args.tau_band,
        args.placements,
        tau_adhesion_work_j_m2=args.tau_adhesion_work,
    )
    materials, notes = _materials(args, surface)
    if args.json:
        out = result.to_json()
        out.update(_elastic_constants(surface))
        out.update(materials)
        out["warnings"] += notes
        print_json(out)
    else:
        _print_result(result)
        _print_materials(materials)
        for note in notes:
            print(f"  warning: {note}")
    return 0


def _elastic_constants(surface: SurfaceParameters) -> dict[str, float]:
    """E* of the pair and the softer body's hardness H (the plasticity index's), from the surface
    the model ran on: the --surface file or the embedded default, with --material's constants."""
    return {"effective_modulus_pa": surface.effective_modulus_pa, "hardness_pa": surface.hardness_pa}


def _materials(args: argparse.Namespace, surface: SurfaceParameters) -> tuple[dict[str, Any], list[str]]:
    """The library's view of the pair (``--material``/``--support-material``) and what it implies."""
    from feeder.materials import adhesion_work, material

    part_material, support_material = materials_from(args)
    if part_material is None and support_material is None:
        return {}, []
    a = part_material or material("silicon")
    b = support_material or a
    w, source = adhesion_work(a, b)
    out = {
        "part_material": a.name if part_material else None,
        "support_material": b.name,
        **_elastic_constants(surface),
        "material_adhesion_work_j_m2": w,
        "material_adhesion_work_source": source,
    }
    notes = []
    measured = [m.tau for m, other in ((a, b), (b, a)) if m.tau and m.tau.partner == other.name]
    if args.tau is None and not measured:
        notes.append(
            f"no shear strength is known for {a.name} on {b.name}: τ is the paper's (silicon on "
            "silicon); give --tau (and --tau-adhesion-work) for this pair"
        )
    if not surface.adhesion_work_j_m2:
        notes.append(
            f"the library's w for {a.name}/{b.name} is {w:.3g} J/m² ({source}); "
            f"--adhesion-work {w:.3g} includes Maugis–Dugdale adhesion"
        )
    return out, notes


def _print_materials(m: dict[str, Any]) -> None:
    """The ``--material`` lines of the text output, in the columns of :func:`_print_result`."""
    if not m:
        return
    part = m["part_material"] or "the surface file's (silicon)"
    print(f"  {'part material':<18}{part}")
    print(f"  {'support material':<18}{m['support_material']}")
    print(f"  {'E*':<18}{m['effective_modulus_pa'] / 1e9:.4g} GPa")
    print(f"  {'hardness H':<18}{m['hardness_pa'] / 1e9:.4g} GPa (the softer body's)")
    print(
        f"  {'library w':<18}{m['material_adhesion_work_j_m2']:.3g} J/m² "
        f"({m['material_adhesion_work_source']})"
    )


def _print_result(r: ContactResult) -> None:
    lo, hi = r.breakaway_force_band_n
    alo, ahi = r.breakaway_accel_band_m_s2
    print(f"part {r.part} µm on {r.support} support")
    print(f"  mass              {r.mass_kg:.5g} kg, weight {r.weight_n:.5g} N")
    print(f"  nominal area      {r.nominal_area_m2:.5g} m²")
    print(f"  separation d      {r.separation_m * 1e9:.4f} nm")
    print(f"  real area A_r     {r.real_area_m2:.5g} m²  ({r.contacts:.3g} asperities in contact)")
    if r.real_area_band_m2 is not None:
        print(
            f"  A_r of placements {r.real_area_band_m2[0]:.5g} – {r.real_area_band_m2[1]:.5g} m²"
            f" (68 %, mean {r.real_area_sampled_mean_m2:.5g})"
        )
    print(f"  τ                 {r.tau_pa / 1e9:.4g} ± {r.tau_band_pa / 1e9:.3g} GPa, {r.tau_source}")
    print(f"  plasticity index  {r.plasticity_index:.3g}")
    if r.summit_tabor is not None:
        print(
            f"  adhesion          {r.adhesion_n:.4g} N pull, {r.attracted_summits:.4g} summits attracted "
            f"out of contact, Maugis λ {r.summit_tabor:.3g} per summit, Fuller–Tabor θ "
            f"{r.adhesion_parameter:.3g}"
        )
    print(f"  breakaway force   {r.breakaway_force_n * 1e6:.4g} µN  [{lo * 1e6:.4g}, {hi * 1e6:.4g}]")
    print(
        f"  breakaway accel   {r.breakaway_accel_m_s2:.4g} m/s²  [{alo:.4g}, {ahi:.4g}]"
        f"  ({r.breakaway_accel_m_s2 / 9.81:.3g} g)"
    )
    for w in r.warnings:
        print(f"  warning: {w}")


def _table(surface: SurfaceParameters, args: argparse.Namespace, placements: int, as_json: bool) -> int:
    rows: list[dict[str, Any]] = []
    warnings: list[str] = []
    tau = tau_band = 0.0
    for label, paper in PAPER_ROWS.items():
        part = Part.parse(label)
        for kind in ("flat", "grooved"):
            r = contact(
                part,
                Support(kind),
                surface,
                args.tau,
                args.tau_band,
                placements,
                tau_adhesion_work_j_m2=args.tau_adhesion_work,
            )
            tau, tau_band = r.tau_pa, r.tau_band_pa
            paper_area = paper.real_area_flat_m2 if kind == "flat" else paper.real_area_grooved_m2
            rows.append(
                {
                    "part": label,
                    "support": kind,
                    "weight_N": r.weight_n,
                    "paper_weight_N": paper.weight_n,
                    "separation_m": r.separation_m,
                    "real_area_m2": r.real_area_m2,
                    "paper_real_area_m2": paper_area,
                    "real_area_deviation": r.real_area_m2 / paper_area - 1.0,
                    "contacts": r.contacts,
                    "real_area_band_m2": r.real_area_band_m2,
                    "real_area_sampled_mean_m2": r.real_area_sampled_mean_m2,
                    "breakaway_force_N": r.breakaway_force_n,
                    "breakaway_accel_m_s2": r.breakaway_accel_m_s2,
                }
            )
            warnings += [
                w for w in r.warnings if w not in warnings and "asperities" not in w and "resting" not in w
            ]
    few = [
        f"{row['part']} {row['support']} ({row['contacts']:.2g})"
        for row in rows
        if row["contacts"] < MIN_CONTACTS
    ]
    if few:
        warnings.insert(
            0,
            f"fewer than {MIN_CONTACTS:g} asperities in contact, Greenwood–Williamson "
            f"statistics unreliable: {', '.join(few)}",
        )
    if as_json:
        print_json({"rows": rows, "tau_pa": tau, "tau_band_pa": tau_band, **_elastic_constants(surface),
                    "warnings": warnings})  # fmt: skip
        return 0
    summits = "Maugis–Dugdale" if surface.adhesion_work_j_m2 else "Hertz"
    print(
        f"Greenwood–Williamson + {summits} contact, model vs paper (Table I, Table III); "
        f"τ = {tau / 1e9:.2f} GPa"
    )
    header = (
        f"{'part µm':<12}{'support':<9}{'weight N':>11}{'d nm':>9}{'A_r 1e-17m²':>13}"
        f"{'paper':>9}{'dev %':>8}{'contacts':>10}{'F_break µN':>12}{'a_break m/s²':>14}"
        f"{'placed A_r 68 %':>18}"
    )
    print(header)
    print("-" * len(header))
    for row in rows:
        print(
            f"{row['part']:<12}{row['support']:<9}{row['weight_N']:>11.5g}"
            f"{row['separation_m'] * 1e9:>9.3f}{row['real_area_m2'] * 1e17:>13.5g}"
            f"{row['paper_real_area_m2'] * 1e17:>9.5g}{row['real_area_deviation'] * 100:>8.2f}"
            f"{row['contacts']:>10.3g}{row['breakaway_force_N'] * 1e6:>12.4g}"
            f"{row['breakaway_accel_m_s2']:>14.4g}{_band_text(row['real_area_band_m2']):>18}"
        )
    print()
    if placements:
        print(
            f"placed A_r: 68 % interval over {placements} random placements, the rigid part at rest on "
            "≥ 3 summits, tilted (1e-17 m²); GW's mean field assumes fractional asperities"
        )
    for w in warnings:
        print(f"warning: {w}")
    return 0


def _band_text(band: tuple[float, float] | None) -> str:
    return "–" if band is None else f"{band[0] * 1e17:.3g}–{band[1] * 1e17:.3g}"
