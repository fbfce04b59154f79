"""``feeder surface``: summit statistics of one or two AFM scans → the GW surface TOML (paper §IV.C)."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from feeder.cli.arguments import float_in, input_path, output_path
from feeder.cli.output import print_json
from feeder.errors import InputError
from feeder.files import save_figure
from feeder.surface.parameters import YOUNGS_MODULUS_RANGE_PA, SurfaceParameters, implausible
from feeder.surface.reading import LENGTH_UNITS_M, PLAIN_SUFFIXES, HeightMap, read_height_map
from feeder.surface.statistics import (
    SurfaceStatistics,
    equivalent_surface,
    find_summits,
    low_pass,
    remove_plane,
    surface_statistics,
)

NOISE_FRACTION_WARNING = 0.1
"""Warn when the summit density exceeds this fraction of pure pixel noise's (summits closer than ~3 px)."""

RADIUS_TAIL_WARNING = 3.0
"""Warn when the mean summit radius exceeds this multiple of 1/(mean curvature): a few nearly flat
summits (quantised heights, noise on a plateau) then make most of the mean R the GW model uses."""

NOTES = (
    "heights are measured from the least-squares mean plane of each scan",
    "sigma_m written to the TOML is Sq (paper eq. 14), not the summit-height std",
    "z_max is not written (default mu + 10 sigma): the highest summit of a small scan "
    "underestimates the highest summit under a part",
)


def register(sub: Any) -> None:
    p = sub.add_parser("surface", help="summit statistics of AFM scans, GW surface TOML")
    p.add_argument(
        "scans",
        nargs="+",
        type=input_path,
        metavar="SCAN",
        help="one scan (rough surface on a smooth plane) or two (both bodies)",
    )
    p.add_argument("--channel", help="channel index or name (default: the file's height channel)")
    p.add_argument(
        "--pixel-size",
        type=float_in(1e-12, 1e-2),
        help="pixel size in m, 1 pm–10 mm, for plain .npy/.txt/.csv height maps",
    )
    p.add_argument(
        "--height-unit",
        help=f"unit of the heights in plain .npy/.txt/.csv height maps, required there "
        f"({', '.join(LENGTH_UNITS_M)})",
    )
    p.add_argument(
        "--youngs-modulus",
        type=float_in(*YOUNGS_MODULUS_RANGE_PA),
        default=169e9,
        help="Young's modulus of both bodies in Pa, 1 MPa–10 TPa (default silicon, 169e9)",
    )
    p.add_argument(
        "--poisson", type=float_in(-1.0, 0.5), default=0.28, help="Poisson ratio, −1–0.5 (default 0.28)"
    )
    p.add_argument(
        "--cutoff-wavelength",
        type=float_in(1e-10, 1.0),
        metavar="M",
        help="Gaussian low-pass (ISO 16610-61, 50 %% at this wavelength in m, 0.1 nm–1 m) "
        "before the "
        "statistics; the unfiltered figures are reported beside",
    )
    p.add_argument(
        "--out", type=output_path, help="write the surface TOML read by `feeder contact --surface`"
    )
    p.add_argument("--plot", type=output_path, help="PNG of the height map(s) with the summits marked")
    p.add_argument(
        "--bem",
        action="store_true",
        help="check GW against ContactMechanics' FFT boundary-element solution on the (one) scan at "
        "the part's nominal pressure and a sweep above it (needs feeder[bem])",
    )
    p.add_argument(
        "--part",
        default="300x300x50",
        help="LxWxT in µm of the silicon part whose nominal pressure --bem uses (default 300x300x50)",
    )
    p.add_argument("--support", default="flat", help="flat or grooved, for --bem's nominal pressure")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if len(args.scans) > 2:
        raise InputError("SCAN", f"give one or two scans, got {len(args.scans)}")
    for target, flag in ((args.out, "--out"), (args.plot, "--plot")):
        if target is not None and (target.is_dir() or not target.parent.is_dir()):
            raise InputError(flag, f"cannot write {target}: a directory, or its directory does not exist")
    maps = [read_height_map(p, args.channel, args.pixel_size, args.height_unit) for p in args.scans]
    ignored = _ignored_scale_options(args)
    unfiltered = [surface_statistics(m) for m in maps] if args.cutoff_wavelength else []
    if args.cutoff_wavelength:
        maps = [
            dataclasses.replace(
                m, heights_m=low_pass(remove_plane(m.heights_m), m.pixel_size_m, args.cutoff_wavelength)
            )
            for m in maps
        ]
    stats = [surface_statistics(m) for m in maps]
    for s in stats:
        if s.summit_count == 0 or not np.isfinite(s.mean_summit_radius_m):
            raise InputError(s.source, "no summits with a fitted radius in this height map")
    if len(stats) == 1:
        surface = stats[0].surface_parameters(args.youngs_modulus, args.poisson)
    else:
        surface = equivalent_surface(stats[0], stats[1], args.youngs_modulus, args.poisson)
    _refuse_implausible(surface, args.scans)
    report = _report(stats, surface)
    report["warnings"] = _resolution_warnings(stats, args.cutoff_wavelength)
    if unfiltered:
        report["cutoff_wavelength_m"] = args.cutoff_wavelength
        report["unfiltered"] = [
            {
                key: getattr(u, key)
                for key in ("sq_m", "summit_density_per_m2", "mean_summit_radius_m", "noise_summit_fraction")
            }
            for u in unfiltered
        ]
    if args.plot is not None:
        _plot(maps, args.plot)
        report["plot"] = str(args.plot)
    if args.out is not None:
        surface.write_toml(args.out)
        report["surface_toml"] = str(args.out)
    if args.bem:
        if len(maps) != 1:
            raise InputError("--bem", "takes one scan (the rough surface on a smooth plane)")
        report.update(_bem(maps[0], surface, args))
        report["warnings"] += report["bem_reading"]
    if args.json:
        report["warnings"] += ignored
        print_json(report)
    else:
        _print_report(report)
    for warning in ignored:  # after the report: a later error stays the only line on stderr
        print(f"feeder surface: warning: {warning}", file=sys.stderr)
    return 0


def _ignored_scale_options(args: argparse.Namespace) -> list[str]:
    """A warning per --pixel-size / --height-unit given with an instrument file: its reader takes
    the file's own scale (only plain .npy/.txt/.csv/.dat height maps read these options)."""
    options = (("--pixel-size", args.pixel_size), ("--height-unit", args.height_unit))
    given = [flag for flag, value in options if value is not None]
    return [
        f"{flag} is ignored for {scan}: the file states its own pixel size and height unit "
        f"(the option is for plain {'/'.join(PLAIN_SUFFIXES)} height maps)"
        for scan in args.scans
        if scan.suffix.lower() not in PLAIN_SUFFIXES
        for flag in given
    ]


def _refuse_implausible(surface: SurfaceParameters, scans: list[Path]) -> None:
    """One line naming the scan(s) and the field when the statistics are physically impossible
    (heights in the wrong unit), before anything is written."""
    problem = implausible(surface)
    if problem is None:
        return
    key, message = problem
    plain = any(p.suffix.lower() in PLAIN_SUFFIXES for p in scans)
    hint = "; check --height-unit" if plain else ""
    raise InputError(f"{', '.join(map(str, scans))}: {key}", message + hint)


def _bem(height_map: HeightMap, surface: SurfaceParameters, args: argparse.Namespace) -> dict[str, Any]:
    """BEM vs GW at the part's nominal pressure and the sweep above it (feeder.contact.bem)."""
    from feeder.contact.bem import compare_with_gw, reading
    from feeder.parts import Part, Support

    part, support = Part.parse(args.part), Support.parse(args.support)
    pressure = part.weight_n / support.nominal_area_m2(part)
    try:
        points, notes = compare_with_gw(
            remove_plane(height_map.heights_m), height_map.pixel_size_m, surface, pressure
        )
    except ArithmeticError as err:
        raise InputError("--bem", str(err)) from None
    nominal = points[0]
    return {
        "bem_part": part.label,
        "bem_support": support.kind,
        "bem_nominal_pressure_pa": pressure,
        "bem_real_area_fraction": nominal.bem_real_area_fraction,
        "gw_real_area_fraction": nominal.gw_real_area_fraction,
        "bem_gw_ratio": nominal.ratio,
        "bem_contact_pixels": nominal.contact_pixels,
        "bem_resolved": nominal.resolved,
        "bem_sweep": [p.to_json() for p in points],
        "bem_reading": reading(points) + notes,
    }


def _resolution_warnings(stats: list[SurfaceStatistics], cutoff: float | None) -> list[str]:
    out = []
    for s in stats:
        if s.noise_summit_fraction > NOISE_FRACTION_WARNING:
            out.append(
                f"{s.source}: summit density {s.summit_density_per_m2 * 1e-12:.4g} µm⁻² is "
                f"{s.noise_summit_fraction:.2f} of what pure pixel noise gives (1/(9 px²)): the summits "
                "are mostly pixel noise, not asperities"
                + ("" if cutoff else "; try --cutoff-wavelength (e.g. 5 pixels)")
            )
        if s.mean_summit_radius_m > RADIUS_TAIL_WARNING * s.radius_from_mean_curvature_m > 0:
            out.append(
                f"{s.source}: mean summit radius {s.mean_summit_radius_m * 1e9:.4g} nm is "
                f"{s.mean_summit_radius_m / s.radius_from_mean_curvature_m:.3g}× 1/(mean curvature) "
                f"{s.radius_from_mean_curvature_m * 1e9:.4g} nm: a few nearly flat summits (quantised "
                "heights, noise on a plateau) make most of the mean R the contact model uses"
                + ("" if cutoff else "; try --cutoff-wavelength (e.g. 5 pixels)")
            )
    return out


def _scan_json(s: SurfaceStatistics) -> dict[str, Any]:
    data = dataclasses.asdict(s)
    data["file"] = data.pop("source")
    return data


def _report(stats: list[SurfaceStatistics], surface: SurfaceParameters) -> dict[str, Any]:
    scans = [_scan_json(s) for s in stats]
    if len(stats) == 1:
        report = dict(scans[0])
    else:
        report = {
            "sq_m": surface.sigma_m,
            "summit_count": sum(s.summit_count for s in stats),
            "summit_density_per_m2": surface.summit_density_per_m2,
            "mean_summit_height_m": surface.mean_summit_height_m,
            "summit_height_std_m": math.hypot(*(s.summit_height_std_m for s in stats)),
            "mean_summit_radius_m": surface.summit_radius_m,
            "pixel_size_m": [list(s.pixel_size_m) for s in stats],
            "scan_size_m": [list(s.scan_size_m) for s in stats],
        }
    report["surface"] = {
        "sigma_m": surface.sigma_m,
        "summit_radius_m": surface.summit_radius_m,
        "summit_density_per_m2": surface.summit_density_per_m2,
        "mean_summit_height_m": surface.mean_summit_height_m,
        "youngs_modulus_pa": surface.youngs_modulus_pa,
        "poisson_ratio": surface.poisson_ratio,
    }
    report["scans"] = scans
    report["notes"] = list(NOTES)
    return report


def _print_report(report: dict[str, Any]) -> None:
    for scan in report["scans"]:
        print(f"{scan['file']}  channel {scan['channel'] or '-'}")
        print(
            f"  scan {scan['scan_size_m'][0] * 1e6:.4g} × {scan['scan_size_m'][1] * 1e6:.4g} µm, "
            f"pixel {scan['pixel_size_m'][0] * 1e9:.4g} × {scan['pixel_size_m'][1] * 1e9:.4g} nm"
        )
        print(
            f"  Sq {scan['sq_m'] * 1e9:.4g} nm; {scan['summit_count']} summits, "
            f"η {scan['summit_density_per_m2'] * 1e-12:.4g} µm⁻²"
        )
        print(
            f"  summit height mean {scan['mean_summit_height_m'] * 1e9:.4g} nm, "
            f"std {scan['summit_height_std_m'] * 1e9:.4g} nm; "
            f"mean radius {scan['mean_summit_radius_m'] * 1e9:.4g} nm "
            f"(1/mean curvature {scan['radius_from_mean_curvature_m'] * 1e9:.4g} nm)"
        )
    s = report["surface"]
    label = "equivalent surface" if len(report["scans"]) == 2 else "surface"
    print(
        f"{label}: σ {s['sigma_m'] * 1e9:.4g} nm, R {s['summit_radius_m'] * 1e9:.4g} nm, "
        f"η {s['summit_density_per_m2'] * 1e-12:.4g} µm⁻², μ {s['mean_summit_height_m'] * 1e9:.4g} nm"
    )
    if "bem_sweep" in report:
        print(f"BEM vs GW, part {report['bem_part']} on {report['bem_support']} support:")
        print(f"  {'pressure Pa':>12}{'BEM A_r/A':>12}{'GW A_r/A':>12}{'BEM/GW':>9}{'pixels':>8}{'GW n':>10}")
        for p in report["bem_sweep"]:
            print(
                f"  {p['pressure_pa']:>12.4g}{p['bem_real_area_fraction']:>12.3g}"
                f"{p['gw_real_area_fraction']:>12.3g}{p['bem_gw_ratio']:>9.3g}{p['bem_contact_pixels']:>8d}"
                f"{p['gw_contacts_on_scan']:>10.3g}"
            )
    for key in ("surface_toml", "plot"):
        if key in report:
            print(f"wrote {report[key]}")
    for note in report["notes"]:
        print(f"note: {note}")
    for warning in report["warnings"]:
        print(f"warning: {warning}")


def _plot(maps: list[HeightMap], path: Path) -> None:
    """Height maps (nm, plane removed) with the summits marked; written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(maps), figsize=(5.5 * len(maps), 4.8), squeeze=False)
    for ax, height_map in zip(axes[0], maps, strict=True):
        heights = remove_plane(height_map.heights_m)
        rows, cols = find_summits(heights)
        d0, d1 = height_map.pixel_size_m
        extent = (0.0, heights.shape[1] * d1 * 1e6, heights.shape[0] * d0 * 1e6, 0.0)
        image = ax.imshow(heights * 1e9, cmap="viridis", extent=extent)
        ax.plot(
            (cols + 0.5) * d1 * 1e6,
            (rows + 0.5) * d0 * 1e6,
            "r.",
            markersize=1.5,
            label=f"{rows.size} summits",
        )
        ax.set_title(Path(height_map.source).name, fontsize=9)
        ax.set_xlabel("µm")
        ax.set_ylabel("µm")
        ax.legend(loc="upper right", fontsize=7)
        fig.colorbar(image, ax=ax, label="height (nm)")
    fig.tight_layout()
    save_figure(fig, path)
