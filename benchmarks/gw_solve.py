"""gw_solve: separation for 1e5 loads, vectorised Newton vs a ``quad`` + ``brentq`` loop.

The baseline integrates eq. 10 in z with ``quad`` (epsabs=0, epsrel=1e-12: the same
accuracy as ours) inside ``brentq`` for each load;
it is timed on a subset and scaled per load.  With quad's default absolute
tolerance (1.49e-8, far above these ~1e-18 integrals) the baseline is ~10x faster
but wrong in the 16th digit of d; that ratio is reported too.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy.integrate import IntegrationWarning, quad
from scipy.optimize import brentq
from timing import best_time

from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.surface.parameters import DEFAULT_SURFACE


def baseline_separation(gw: GreenwoodWilliamson, load: float, epsabs: float = 0.0) -> float:
    s = gw.surface
    hertz = 4.0 / 3.0 * s.effective_modulus_pa * math.sqrt(s.summit_radius_m) * gw.summits
    norm = 1.0 / (math.sqrt(2.0 * math.pi) * s.sigma_m)

    def carried(d: float) -> float:
        def f(z: float) -> float:
            return (z - d) ** 1.5 * norm * math.exp(-0.5 * ((z - s.mean_summit_height_m) / s.sigma_m) ** 2)

        return hertz * quad(f, d, s.z_max, epsabs=epsabs, epsrel=1e-12)[0] - load

    with warnings.catch_warnings():  # quad complains it cannot reach 1e-12 on some loads; fine here
        warnings.simplefilter("ignore", IntegrationWarning)
        return float(brentq(carried, s.mean_summit_height_m - 6 * s.sigma_m, s.z_max, xtol=1e-22))


def run(quick: bool = False) -> dict[str, float]:
    gw = GreenwoodWilliamson(DEFAULT_SURFACE, 9e-8)  # 300 × 300 µm, flat
    count = 10_000 if quick else 100_000
    loads = np.random.default_rng(2).uniform(1e-9, 1e-6, count)
    subset = loads[: 10 if quick else 40]
    baseline = best_time(lambda: [baseline_separation(gw, x) for x in subset], repeats=1) / subset.size
    loose = best_time(lambda: [baseline_separation(gw, x, 1.49e-8) for x in subset], repeats=1)
    ours = best_time(lambda: gw.separation_m(loads)) / count
    check = max(abs(baseline_separation(gw, x) - float(gw.separation_m(x))) for x in subset[:3])
    return {
        "ratio": baseline / ours,
        "loads": count,
        "baseline_us_per_load": baseline * 1e6,
        "ours_us_per_load": ours * 1e6,
        "ratio_vs_quad_default_tolerance": loose / subset.size / ours,
        "max_abs_difference_m": check,
    }
