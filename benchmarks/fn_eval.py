"""fn_eval: F_{3/2}(h) for 1e5 values, ours vs ``scipy.integrate.quad`` per value.

The baseline is timed on a subset and scaled per value (it would take minutes).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import quad
from timing import best_time

from feeder.contact.gaussian_integrals import gaussian_integral

INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


def quad_fn(n: float, h: float) -> float:
    return (
        INV_SQRT_2PI
        * quad(lambda s: (s - h) ** n * math.exp(-0.5 * s * s), h, math.inf, epsabs=0.0, epsrel=1e-12)[0]
    )


def run(quick: bool = False) -> dict[str, float]:
    rng = np.random.default_rng(1)
    count = 10_000 if quick else 100_000
    h = rng.uniform(-8.0, 12.0, count)
    subset = h[: 200 if quick else 1000]
    baseline = best_time(lambda: [quad_fn(1.5, x) for x in subset], repeats=1) / subset.size
    ours = {n: best_time(lambda n=n: gaussian_integral(n, h)) / count for n in (0.0, 1.0, 1.5)}
    return {
        "ratio": baseline / ours[1.5],
        "values": count,
        "quad_us_per_value": baseline * 1e6,
        "f32_us_per_value": ours[1.5] * 1e6,
        "f0_us_per_value": ours[0.0] * 1e6,
        "f1_us_per_value": ours[1.0] * 1e6,
    }
