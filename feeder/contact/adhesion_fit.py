"""The work of adhesion w that makes the grooved/flat real-area ratio match the measured
friction ratio (0.74 for the 300×300 part), with GW-MD summits, and how sharply it is fixed.

ratio(w) = A_r(grooved, w) / A_r(flat, w) at the part's weight; without adhesion it is
≈ 0.99 (GW/Hertz: halving the summits at the same load barely changes A_r), and once
adhesion dominates the weight it tends to the nominal-area ratio 0.5 (A_r ∝ A_n).  The
fit solves ratio(w) = target by Brent's method on log w; the sensitivity d ratio / d w
is a central difference, and the w band is where ratio(w) crosses the ends of the
ratio band.  A target outside the range ratio(w) spans is reported, not forced; a target that
is no area ratio (outside (0, 1]), or a band that is reversed or leaves the target out, is an
:class:`~feeder.errors.InputError` (:func:`check_ratios`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import brentq

from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.errors import InputError
from feeder.paper import GROOVED_FRICTION_RATIO
from feeder.parts import FLAT, GROOVED, Part
from feeder.surface.parameters import SurfaceParameters

W_RANGE_J_M2 = (1e-4, 1.0)
"""Works of adhesion searched (J/m²)."""
RATIO_BAND = (0.70, 0.78)
"""Band of the measured grooved/flat ratio (two force curves per support, ≈ ± 0.04)."""


def check_ratios(target: float, band: tuple[float, float]) -> None:
    """:class:`InputError` naming ``target`` or ``band`` unless 0 < LO < HI ≤ 1 and LO ≤ target ≤ HI.

    A grooved/flat ratio of real areas lies in (0, 1]: the grooved support has half the
    summits under the same weight (0.5 at most adhesion, ≈ 0.99 without), never more.
    """
    if not (math.isfinite(target) and 0 < target <= 1):
        raise InputError("target", f"a grooved/flat area ratio lies in (0, 1], got {target!r}")
    lo, hi = band
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi <= 1):
        raise InputError("band", f"expected LO < HI within (0, 1], got {lo!r} {hi!r}")
    if not lo <= target <= hi:
        raise InputError("band", f"{lo:g}–{hi:g} does not contain the target ratio {target:g}")


def default_band(target: float) -> tuple[float, float]:
    """The ratio band for ``target`` when none is given: the measured :data:`RATIO_BAND` if it
    holds the target, else its half-width (± 0.04, the spread of two force curves) around the
    target, kept within (0, 1]."""
    if RATIO_BAND[0] <= target <= RATIO_BAND[1]:
        return RATIO_BAND
    half = (RATIO_BAND[1] - RATIO_BAND[0]) / 2
    return max(target - half, target / 2), min(target + half, 1.0)


def grooved_ratio(surface: SurfaceParameters, part: Part, adhesion_work_j_m2: float) -> float:
    """A_r grooved / A_r flat for ``part`` at its weight with work of adhesion w."""
    s = replace(surface, adhesion_work_j_m2=adhesion_work_j_m2)
    areas = []
    for support in (GROOVED, FLAT):
        gw = GreenwoodWilliamson(s, support.nominal_area_m2(part))
        areas.append(float(gw.real_area_m2(gw.separation_m(part.weight_n))))
    return areas[0] / areas[1]


@dataclass(frozen=True)
class AdhesionFit:
    """The fitted w (None if no w in :data:`W_RANGE_J_M2` reaches the target) and its sensitivity."""

    target_ratio: float
    adhesion_work_j_m2: float | None
    ratio_slope_per_j_m2: float | None
    adhesion_work_band_j_m2: tuple[float, float] | None
    ratio_range: tuple[float, float]
    curve_w_j_m2: tuple[float, ...]
    curve_ratio: tuple[float, ...]
    explanation: str


def fit_adhesion_work(
    surface: SurfaceParameters,
    part: Part,
    target: float = GROOVED_FRICTION_RATIO,
    band: tuple[float, float] | None = None,
    curve_points: int = 13,
) -> AdhesionFit:
    """Fit w to ``target`` (module docstring); ``curve_points`` ratios on a log grid of w; the w
    band from ``band`` (default :func:`default_band`).

    :class:`InputError` (:func:`check_ratios`) for a target or band that is no area ratio.
    """
    band = default_band(target) if band is None else band
    check_ratios(target, band)
    ws = np.geomspace(*W_RANGE_J_M2, curve_points)
    ratios = np.array([grooved_ratio(surface, part, float(w)) for w in ws])
    lo_r, hi_r = float(ratios.min()), float(ratios.max())

    def solve(r: float) -> float | None:
        crossing = np.flatnonzero(np.diff(np.sign(ratios - r)) != 0)
        if crossing.size == 0:
            return None
        k = int(crossing[0])
        x = brentq(lambda lw: grooved_ratio(surface, part, math.exp(lw)) - r,
                   math.log(ws[k]), math.log(ws[k + 1]), xtol=1e-7)  # fmt: skip
        return math.exp(x)

    w = solve(target)
    if w is None:
        return AdhesionFit(target, None, None, None, (lo_r, hi_r), tuple(ws), tuple(ratios),
                           f"no w in {W_RANGE_J_M2[0]:g}–{W_RANGE_J_M2[1]:g} J/m² gives the ratio "
                           f"{target:g}: the model spans {lo_r:.3f}–{hi_r:.3f}")  # fmt: skip
    step = 1e-3 * w
    slope = (grooved_ratio(surface, part, w + step) - grooved_ratio(surface, part, w - step)) / (2 * step)
    ends = [e for e in (solve(r) for r in band) if e is not None]
    w_band = (min(ends), max(ends)) if len(ends) == 2 else None
    return AdhesionFit(
        target, w, slope, w_band, (lo_r, hi_r), tuple(ws), tuple(ratios),
        f"w = {w:.4g} J/m² gives the ratio {target:g}; d ratio/d w = {slope:.4g} per J/m²: the ratio "
        "falls from ≈ 0.99 (no adhesion) to 0.5 (adhesion-dominated, A_r ∝ nominal area)",
    )  # fmt: skip
