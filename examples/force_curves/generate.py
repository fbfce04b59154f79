"""Generate the example friction force curves in this folder (the paper's raw curves are not public).

    python examples/force_curves/generate.py [OUTDIR]

Each curve is made by :func:`feeder.friction.synthetic_curves.synthetic_force_curve`:
free approach with a baseline offset (150 nm), linear drift (20 nm over the curve) and
white deflection noise (1 nm rms), a softening loading branch up to the static-friction
peak, a slip to 80 % of it and stick-slip ripple. The peaks are the paper's measured
forces (Table IV: 300×300 µm part on the flat and grooved supports, TL-FM cantilever;
Table V: the 80×80 µm part's mean, NSC35 cantilever). The true peak is written in each
file's header (``true_static_friction_n``) so the analysis can be checked:

    feeder friction examples/force_curves/flat_300x300_*.csv
"""

from __future__ import annotations

import sys
from pathlib import Path

from feeder.friction.cantilevers import CANTILEVERS
from feeder.friction.force_curves import write_force_curve
from feeder.friction.synthetic_curves import synthetic_force_curve

# file stem: (peak force N, cantilever, part, support, seed)
CURVES = {
    "flat_300x300_1": (0.9759e-6, "TL-FM", "300x300x50", "flat", 1),
    "flat_300x300_2": (0.9174e-6, "TL-FM", "300x300x50", "flat", 2),
    "grooved_300x300_1": (0.7078e-6, "TL-FM", "300x300x50", "grooved", 3),
    "grooved_300x300_2": (0.6962e-6, "TL-FM", "300x300x50", "grooved", 4),
    "flat_80x80_1": (0.08e-6, "NSC35", "80x80x50", "flat", 5),
}


def main(out: Path) -> None:
    for stem, (peak, lever, part, support, seed) in CURVES.items():
        stiffness = CANTILEVERS[lever].stiffness_n_per_m
        displacement, deflection = synthetic_force_curve(peak, stiffness, seed=seed)
        metadata = {
            "generated_by": f"examples/force_curves/generate.py (seed {seed})",
            "cantilever": lever,
            "part": part,
            "support": support,
            "true_static_friction_n": f"{peak:.6e}",
        }
        write_force_curve(out / f"{stem}.csv", displacement, deflection, metadata)
        print(f"wrote {out / f'{stem}.csv'}", file=sys.stderr)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent)
