"""gw_md_solve: separation of the GW-MD contact (Maugis–Dugdale summits, attraction out of
contact) for many loads, vectorised, vs a pointwise quadrature reference.

The baseline is tests/test_gw_maugis_dugdale.py's reference: the net load integrated in z
with ``quad``, each summit's MD state solved by ``brentq`` at every quadrature point; the
separation is the largest root (stepping down from the Hertz separation by σ/4, then
``brentq``).  It is timed on a few loads and scaled per load; ours includes building the
surface's quadrature nodes (``SummitLaw``, cache cleared) and the h scan.
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.integrate import IntegrationWarning
from scipy.optimize import brentq
from timing import best_time

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_gw_maugis_dugdale import MaugisDugdaleReference

from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.contact.gw_maugis_dugdale import SummitLaw
from feeder.surface.parameters import DEFAULT_SURFACE

AREA_M2 = 9e-8  # 300 × 300 µm, flat
ADHESION_WORK_J_M2 = 0.0168  # the w that gives the grooved/flat ratio 0.74


def baseline_separation(ref: MaugisDugdaleReference, load: float) -> float:
    s = ref.s
    with warnings.catch_warnings():  # quad cannot always reach 1e-13 on the Hertz part; fine here
        warnings.simplefilter("ignore", IntegrationWarning)
        return _largest_root(ref, load, s.sigma_m)


def _largest_root(ref: MaugisDugdaleReference, load: float, sigma_m: float) -> float:
    top = ref.separation(load)  # Hertz: adhesion only adds compression, so the largest root is below
    lo = top
    while ref.net_load(lo) < load:
        top, lo = lo, lo - 0.25 * sigma_m
    return float(brentq(lambda d: ref.net_load(d) - load, lo, top, xtol=1e-22, rtol=1e-13))


def run(quick: bool = False) -> dict[str, float]:
    surface = replace(DEFAULT_SURFACE, adhesion_work_j_m2=ADHESION_WORK_J_M2)
    ref = MaugisDugdaleReference(surface, AREA_M2)
    count = 2_000 if quick else 20_000
    loads = np.random.default_rng(3).uniform(1e-8, 1e-6, count)
    subset = loads[: 1 if quick else 3]
    baseline = best_time(lambda: [baseline_separation(ref, x) for x in subset], repeats=1) / subset.size

    def ours() -> np.ndarray:
        SummitLaw.of.cache_clear()
        return GreenwoodWilliamson(surface, AREA_M2).separation_m(loads)

    ours_time = best_time(ours) / count
    gw = GreenwoodWilliamson(surface, AREA_M2)
    check = max(abs(baseline_separation(ref, x) - float(gw.separation_m(x))) for x in subset[:1])
    return {
        "ratio": baseline / ours_time,
        "loads": count,
        "baseline_ms_per_load": baseline * 1e3,
        "ours_us_per_load": ours_time * 1e6,
        "max_abs_difference_m": check,
    }
