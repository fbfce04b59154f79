"""One sphere on a flat with adhesion: Hertz, DMT, JKR and Maugis–Dugdale (DESIGN §11).

A sphere of radius R against a flat, reduced modulus E* (K = 4E*/3), work of
adhesion w.  Johnson's units (Johnson & Greenwood 1997):

    ā = a (K/(πwR²))^{1/3},   P̄ = P/(πwR),   δ̄ = δ (K²/(π²w²R))^{1/3}.

Closed forms:  Hertz  P̄ = ā³, δ̄ = ā²;  DMT  P̄ = ā³ − 2, δ̄ = ā²;
JKR  P̄ = ā³ − √6·ā^{3/2}, δ̄ = ā² − (2/3)√6·ā^{1/2}.

Maugis–Dugdale (Maugis 1992, eqs. 6.17 ff.): a Dugdale stress σ₀ acts over the
annulus a < r < c, out to where the gap reaches h₀ = w/σ₀; Maugis' parameter
λ = 2σ₀ (R/(πwK²))^{1/3} (Tabor's μ ≈ λ/1.16).  With m = c/a and t = √(m²−1):

    (λā²/2)[t + (m²−2)·atan t] + (4λ²ā/3)[t·atan t − m + 1] = 1
    P̄ = ā³ − λā²[t + m²·atan t],   δ̄ = ā² − (4/3)λā·t.

The left side increases strictly with t (its t-derivative is positive), so t is
unique; it is found by bisection on t (vectorised, to machine precision), with
m − 1 written as t²/(m + 1) so nothing cancels at large ā.

Out of contact (a = 0, Maugis' non-contact branch) the attraction acts over a
disc of radius c and deforms the surfaces; the gap at r = c equals h₀:

    c̄²/2 − (8λ/3π)·c̄ = 2/(πλ) + δ̄,   P̄ = −(πλ/2)·c̄²,

which joins the contact branch at ā → 0, where δ̄ = −(4/3)λc̄.  Pull-off under
load control is −min P̄ over the equilibrium curve (2 for DMT, 1.5 for JKR).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq, minimize_scalar

from feeder.errors import InputError
from feeder.surface.parameters import DEFAULT_ADHESION_RANGE_M

Model = Literal["hertz", "dmt", "jkr", "maugis-dugdale"]
MODELS: tuple[str, ...] = ("hertz", "dmt", "jkr", "maugis-dugdale")
DEFAULT_RANGE_M = DEFAULT_ADHESION_RANGE_M
"""Default Dugdale range h₀ = 0.971·z₀: Maugis' match of the Dugdale law to a Lennard-Jones
one (σ₀ = 1.03·w/z₀, so λ = 1.16·μ)."""
_BISECTIONS = 110
_SQRT6 = math.sqrt(6.0)


def _md_t(abar: NDArray[np.float64], lam: float) -> NDArray[np.float64]:
    """t = √(m²−1) solving Maugis' equation for each ā > 0 (vectorised bisection)."""
    lo = np.zeros_like(abar)
    hi = np.ones_like(abar)
    while True:
        short = _md_residual(hi, abar, lam) < 0
        if not short.any():
            break
        hi = np.where(short, 4.0 * hi, hi)
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        above = _md_residual(mid, abar, lam) > 0
        lo, hi = np.where(above, lo, mid), np.where(above, mid, hi)
    return 0.5 * (lo + hi)


def _md_residual(t: NDArray[np.float64], abar: NDArray[np.float64], lam: float) -> NDArray[np.float64]:
    m = np.sqrt(1.0 + t * t)
    at = np.arctan(t)
    first = 0.5 * lam * abar**2 * (t + (t * t - 1.0) * at)
    second = 4.0 / 3.0 * lam**2 * abar * (t * at - t * t / (m + 1.0))
    return np.asarray(first + second - 1.0)


def maugis_dugdale(abar: ArrayLike, lam: float) -> tuple[NDArray[np.float64], ...]:
    """(P̄, δ̄, m) on MD's contact branch at contact radii ``abar`` > 0 (Johnson's units)."""
    a = np.atleast_1d(np.asarray(abar, dtype=np.float64))
    t = _md_t(a, lam)
    m = np.sqrt(1.0 + t * t)
    at = np.arctan(t)
    load = a**3 - lam * a**2 * (t + m * m * at)
    approach = a**2 - 4.0 / 3.0 * lam * a * t
    return load, approach, m


def md_edge_of_contact(lam: float) -> float:
    """c̄ at ā → 0: root of πλc̄²/4 + (4λ²/3)(π/2 − 1)c̄ = 1."""
    qa, qb = math.pi * lam / 4.0, 4.0 / 3.0 * lam**2 * (math.pi / 2.0 - 1.0)
    return 2.0 / (qb + math.sqrt(qb * qb + 4.0 * qa))


def md_pull_off(lam: float) -> tuple[float, float]:
    """(pull-off −min P̄ under load control, ā where it happens; 0 = at the edge ā → 0)."""
    edge = md_edge_of_contact(lam)
    at_edge = math.pi * lam / 2.0 * edge**2
    grid = np.geomspace(1e-6, 20.0, 400)
    loads = maugis_dugdale(grid, lam)[0]
    k = int(np.argmin(loads))
    if k == 0 or loads[k] >= -at_edge:
        return at_edge, 0.0
    k = min(k, grid.size - 2)
    best = minimize_scalar(
        lambda x: float(maugis_dugdale(x, lam)[0][0]), bracket=(grid[k - 1], grid[k], grid[k + 1]), tol=1e-12
    )
    return -float(best.fun), float(best.x)


@dataclass(frozen=True)
class SphereContact:
    """Sphere on a flat (SI): radius R, reduced modulus E*, work of adhesion w, Maugis' λ."""

    radius_m: float
    modulus_pa: float
    adhesion_work_j_m2: float
    tabor: float

    def __post_init__(self) -> None:
        for name in ("radius_m", "modulus_pa"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"--{name.split('_')[0]}", f"must be a positive number, got {value!r}")
        if not (math.isfinite(self.adhesion_work_j_m2) and self.adhesion_work_j_m2 >= 0):
            raise InputError("--adhesion-work", f"must be ≥ 0, got {self.adhesion_work_j_m2!r}")
        if not (math.isfinite(self.tabor) and self.tabor > 0):
            raise InputError("--tabor", f"must be a positive number, got {self.tabor!r}")

    @classmethod
    def from_range(
        cls, radius_m: float, modulus_pa: float, adhesion_work_j_m2: float, range_m: float = DEFAULT_RANGE_M
    ) -> SphereContact:
        """λ from the Dugdale range h₀ (σ₀ = w/h₀)."""
        if not (math.isfinite(range_m) and range_m > 0):
            raise InputError("--range", f"must be a positive length in m, got {range_m!r}")
        k = 4.0 * modulus_pa / 3.0
        w = adhesion_work_j_m2
        lam = 2.0 * (w / range_m) * (radius_m / (math.pi * w * k * k)) ** (1 / 3) if w > 0 else 1.0
        return cls(radius_m, modulus_pa, adhesion_work_j_m2, lam)

    @property
    def k_pa(self) -> float:
        return 4.0 * self.modulus_pa / 3.0

    @property
    def load_unit_n(self) -> float:
        """πwR (N)."""
        return math.pi * self.adhesion_work_j_m2 * self.radius_m

    @property
    def radius_unit_m(self) -> float:
        """(πwR²/K)^{1/3} (m)."""
        return float((self.load_unit_n * self.radius_m / self.k_pa) ** (1 / 3))

    @property
    def approach_unit_m(self) -> float:
        """(π²w²R/K²)^{1/3} = unit radius²/R (m)."""
        return self.radius_unit_m**2 / self.radius_m

    @property
    def dugdale_stress_pa(self) -> float:
        """σ₀ = λ (πwK²/R)^{1/3}/2."""
        return self.tabor * (math.pi * self.adhesion_work_j_m2 * self.k_pa**2 / self.radius_m) ** (1 / 3) / 2

    @property
    def dugdale_range_m(self) -> float:
        """h₀ = w/σ₀ (m); inf without adhesion."""
        stress = self.dugdale_stress_pa
        return self.adhesion_work_j_m2 / stress if stress > 0 else math.inf

    def pull_off_n(self, model: str) -> float:
        """Pull-off force under load control (N, positive; 0 for Hertz)."""
        factor = {"hertz": 0.0, "dmt": 2.0, "jkr": 1.5}.get(model)
        if factor is None:
            factor = md_pull_off(self.tabor)[0]
        return factor * self.load_unit_n

    def curve(self, model: str, max_load_n: float, points: int = 200) -> tuple[NDArray[np.float64], ...]:
        """(load N, contact radius m, approach m) along the equilibrium curve, from the
        smallest contact up to ``max_load_n``."""
        if model == "hertz" or self.adhesion_work_j_m2 == 0:
            a_max = (max_load_n * self.radius_m / self.k_pa) ** (1 / 3)
            a = np.linspace(0.0, a_max, points)
            return self.k_pa * a**3 / self.radius_m, a, a**2 / self.radius_m
        a_max = self.state_at_load(model, max_load_n)[0] / self.radius_unit_m
        abar = np.linspace(a_max / points, a_max, points)
        load, approach = self._normalised(model, abar)
        return load * self.load_unit_n, abar * self.radius_unit_m, approach * self.approach_unit_m

    def _normalised(self, model: str, abar: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        if model == "dmt":
            return abar**3 - 2.0, abar**2
        if model == "jkr":
            return abar**3 - _SQRT6 * abar**1.5, abar**2 - 2.0 / 3.0 * _SQRT6 * np.sqrt(abar)
        load, approach, _ = maugis_dugdale(abar, self.tabor)
        return load, approach

    def state_at_load(self, model: str, load_n: float) -> tuple[float, float]:
        """(contact radius m, approach m) at ``load_n`` on the stable branch (load control)."""
        if not math.isfinite(load_n):
            raise InputError("--load", f"must be a finite force in N, got {load_n!r}")
        if model == "hertz" or self.adhesion_work_j_m2 == 0:
            if load_n < 0:
                raise InputError("--load", "a Hertz contact carries no tension")
            a = (load_n * self.radius_m / self.k_pa) ** (1 / 3)
            return a, a * a / self.radius_m
        pull_off = self.pull_off_n(model)
        if load_n < -pull_off:
            raise InputError(
                "--load",
                f"{load_n:.4g} N is beyond the pull-off force ({pull_off:.4g} N): the sphere separates",
            )
        target = load_n / self.load_unit_n
        if model == "dmt":
            abar = (target + 2.0) ** (1 / 3)
        elif model == "jkr":  # ā^{3/2} = (√6 + √(6 + 4P̄))/2
            abar = (0.5 * (_SQRT6 + math.sqrt(max(6.0 + 4.0 * target, 0.0)))) ** (2 / 3)
        else:
            start = md_pull_off(self.tabor)[1]
            hi = max(2.0 * start, 1.0)
            while self._normalised(model, np.array([hi]))[0][0] < target:
                hi *= 2.0
            low = max(start, 1e-9)
            if self._normalised(model, np.array([low]))[0][0] >= target:
                abar = low
            else:
                abar = brentq(
                    lambda x: float(self._normalised(model, np.array([x]))[0][0]) - target,
                    low,
                    hi,
                    xtol=1e-14,
                    rtol=1e-13,
                )
        approach = float(self._normalised(model, np.array([abar]))[1][0])
        return abar * self.radius_unit_m, approach * self.approach_unit_m
