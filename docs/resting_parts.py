"""Writes docs/resting-parts.png: A_r of a rigid part at rest on its summits against GW's mean field.

    python docs/resting_parts.py [--placements N] [--surface TOML]

Left: A_r / A_r(GW) over random placements of the 80×80×50 and 300×300×50 µm
silicon parts on the flat support, the part at rest tilted on ≥ 3 summits
(feeder.contact.resting_part) and, for comparison, lowered level (one summit may
carry it; feeder.contact.asperity_sampling).  Right: the mean and 68 % band of
A_r / A_r(GW) against the part's side, at the same nominal pressure (50 µm of
silicon): the trend towards GW as the number of contacts grows.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from feeder.contact.asperity_sampling import sample_contact
from feeder.contact.resting_part import rest_part
from feeder.files import save_figure
from feeder.parts import Part
from feeder.surface.parameters import DEFAULT_SURFACE, load_surface

OUT = Path(__file__).with_name("resting-parts.png")
SIDES_UM = (80, 150, 300, 600, 1000, 2000, 4000)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--placements", type=int, default=2000)
    parser.add_argument("--surface", type=Path, help="surface TOML (default: the embedded surface)")
    args = parser.parse_args()
    surface = load_surface(args.surface) if args.surface else DEFAULT_SURFACE
    fig, (hist, trend) = plt.subplots(1, 2, figsize=(11, 4.2))
    for side, colour in ((80, "C3"), (300, "C0")):
        part = Part.parse(f"{side}x{side}x50")
        rest = rest_part(surface, part, placements=args.placements)
        level = sample_contact(surface, part.footprint_m2, part.weight_n, args.placements)
        bins = np.linspace(0.5, 4.0, 71)
        hist.hist(
            rest.real_area_m2 / rest.gw_real_area_m2,
            bins,
            color=colour,
            alpha=0.55,
            label=f"{side}×{side} at rest (mean {np.mean(rest.real_area_m2) / rest.gw_real_area_m2:.2f})",
        )
        hist.hist(
            level.real_area_m2 / rest.gw_real_area_m2,
            bins,
            color=colour,
            histtype="step",
            linestyle="--",
            label=f"{side}×{side} level (mean {np.mean(level.real_area_m2) / rest.gw_real_area_m2:.2f})",
        )
        print(
            f"{side}x{side}: at rest {np.mean(rest.real_area_m2) / rest.gw_real_area_m2:.3f} x GW "
            f"± {np.std(rest.real_area_m2) / np.mean(rest.real_area_m2):.3f}, contacts median "
            f"{np.median(rest.contacts):g}, GW expects {rest.gw_contacts:.3g}"
        )
    hist.axvline(1.0, color="k", lw=0.8)
    hist.set_xlabel("A_r / A_r(GW)")
    hist.set_ylabel("placements")
    hist.legend(fontsize=8)
    hist.set_title("one placement's real area (flat support)")
    for label, sampler, marker in (("at rest, tilted, ≥ 3 contacts", "rest", "o"), ("level", "level", "s")):
        mean, lo, hi, contacts = [], [], [], []
        for side in SIDES_UM:
            part = Part.parse(f"{side}x{side}x50")
            placements = max(100, args.placements * 300 // max(side, 300))
            rest = rest_part(surface, part, placements=placements)
            area = rest.real_area_m2
            if sampler == "level":
                area = sample_contact(surface, part.footprint_m2, part.weight_n, placements).real_area_m2
            ratio = area / rest.gw_real_area_m2
            mean.append(np.mean(ratio))
            lo.append(np.quantile(ratio, 0.1587))
            hi.append(np.quantile(ratio, 0.8413))
            contacts.append(rest.gw_contacts)
        trend.errorbar(
            SIDES_UM,
            mean,
            yerr=[np.subtract(mean, lo), np.subtract(hi, mean)],
            marker=marker,
            capsize=3,
            label=label,
        )
    for side, n in zip(SIDES_UM, contacts, strict=True):
        trend.annotate(f"{n:.2g}", (side, 0.8), ha="center", fontsize=7)
    trend.text(SIDES_UM[0], 0.72, "GW's expected contacts:", fontsize=7)
    trend.axhline(1.0, color="k", lw=0.8)
    trend.set_xscale("log")
    trend.set_ylim(0.65, 3.6)
    trend.set_xlabel("part side (µm), 50 µm thick silicon")
    trend.set_ylabel("A_r / A_r(GW): mean, 68 % band")
    trend.legend(fontsize=8)
    trend.set_title("towards GW as the part grows")
    fig.tight_layout()
    save_figure(fig, OUT)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
