"""Greenwood–Williamson multi-asperity contact with Hertzian asperities (paper eqs. 4–11).

An equivalent rough surface (summit heights Gaussian, mean μ, std σ, radius R,
density η) against a smooth plane at separation d.  With h = (d − μ)/σ and the
highest summit H = (z_max − μ)/σ:

    n(d)   = N F_0(h, H)                              (eq. 4)
    A_r(d) = π N R σ F_1(h, H)                        (eqs. 5, 9, 11)
    P_r(d) = 4/3 N E* R^½ σ^{3/2} F_{3/2}(h, H)       (eqs. 6, 8, 10)

N = η A_n.  All of it vectorised over d (or over loads for the inverse).

With a work of adhesion w > 0 (``SurfaceParameters.adhesion_work_j_m2``) every
summit follows the Maugis–Dugdale law, summits just out of contact (within the
Dugdale range) pulling too (:mod:`feeder.contact.gw_maugis_dugdale`): the load and
area are the Hertz integrals above plus the MD corrections ΔP(d) ≤ 0, ΔA(d) ≥ 0,
and n counts the summits whose MD contact radius is positive.  The paper leaves
adhesion out (its future work).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from feeder.contact.gaussian_integrals import H_MIN, gaussian_integral, gaussian_integrals
from feeder.contact.gw_maugis_dugdale import SummitLaw
from feeder.errors import InputError
from feeder.surface.parameters import SurfaceParameters

_TABLE_POINTS = 40001
_ACCEPT_STEP = 1e-6
_ACCEPT_STEP_LINEAR = 1e-12
_SCAN_STEP = 0.02
"""Grid step in h for the largest root of the (non-monotone) GW-MD net load."""
_MAX_NEWTON = 60


def _newton(
    h: NDArray[np.float64],
    lo: float | NDArray[np.float64],
    hi: float | NDArray[np.float64],
    residual_and_step: Callable[[NDArray[np.float64], NDArray[np.intp]], tuple[NDArray[np.float64], ...]],
    accept_step: float,
) -> NDArray[np.float64]:
    """Safeguarded Newton on a residual decreasing in h, bracket [lo, hi], vectorised.

    ``residual_and_step(x, idx)`` gives the residual at x (the values ``idx``)
    and the Newton step; a step leaving the bracket is replaced by bisection.
    Only unconverged values are iterated.
    """
    low = np.broadcast_to(np.asarray(lo, dtype=np.float64), h.shape).copy()
    high = np.broadcast_to(np.asarray(hi, dtype=np.float64), h.shape).copy()
    active = np.arange(h.size)
    for _ in range(_MAX_NEWTON):
        x, a, b = h[active], low[active], high[active]
        residual, step = residual_and_step(x, active)
        a = np.where(residual > 0, x, a)
        b = np.where(residual < 0, x, b)
        inside = (x + step >= a) & (x + step <= b)
        # quadratic convergence: the error after an accepted step is ~|g''/2g'|·step²
        converged = inside & (np.abs(step) <= accept_step) | (b - a <= 1e-13)
        h[active] = np.where(inside, x + step, 0.5 * (a + b))
        low[active], high[active] = a, b
        active = active[~converged]
        if active.size == 0:
            return h
    raise ArithmeticError("separation: Newton iteration did not converge")


class GreenwoodWilliamson:
    """GW + Hertz contact of ``surface`` over the nominal area ``nominal_area_m2`` (m²)."""

    def __init__(self, surface: SurfaceParameters, nominal_area_m2: float) -> None:
        if not (math.isfinite(nominal_area_m2) and nominal_area_m2 > 0):
            raise InputError("nominal_area_m2", f"must be positive, got {nominal_area_m2!r}")
        self.surface = surface
        self.nominal_area_m2 = nominal_area_m2
        self.summits = surface.summit_density_per_m2 * nominal_area_m2
        """N = η A_n, the number of summits under the nominal area."""
        s = surface
        self._h_max = (s.z_max - s.mean_summit_height_m) / s.sigma_m
        self._load_scale = (
            4.0 / 3.0 * self.summits * s.effective_modulus_pa * math.sqrt(s.summit_radius_m) * s.sigma_m**1.5
        )
        self._area_scale = math.pi * self.summits * s.summit_radius_m * s.sigma_m
        self._table: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self._scan: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self.summit_law: SummitLaw | None = None
        """Per-summit Maugis–Dugdale law (None without adhesion)."""
        if s.adhesion_work_j_m2 > 0:
            deepest = s.z_max - (s.mean_summit_height_m + H_MIN * s.sigma_m)
            self.summit_law = SummitLaw.of(s, deepest)

    def _corrections(self, h: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        """MD corrections to load (N), area (m²) and d(load)/dh (N) at h (zeros without adhesion)."""
        law = self.summit_law
        if law is None:
            zero = np.zeros_like(h)
            return zero, zero, zero
        s = self.surface
        unit = law.sphere.approach_unit_m / s.sigma_m  # δ₀/σ
        x = h.ravel()[:, None] + unit * law.approach[None, :]  # (z − μ)/σ at each node
        inside = x <= (s.z_max - s.mean_summit_height_m) / s.sigma_m
        density = np.where(inside, np.exp(-0.5 * x * x), 0.0) * (unit / math.sqrt(2.0 * math.pi))
        weighted = density * law.weight
        load = self.summits * law.sphere.load_unit_n * (weighted @ law.load)
        area = self.summits * math.pi * law.sphere.radius_unit_m**2 * (weighted @ law.area)
        slope = -self.summits * law.sphere.load_unit_n * ((weighted * x) @ law.load)
        return load.reshape(h.shape), area.reshape(h.shape), slope.reshape(h.shape)

    def _h(self, separation_m: ArrayLike) -> NDArray[np.float64]:
        d = np.asarray(separation_m, dtype=np.float64)
        return (d - self.surface.mean_summit_height_m) / self.surface.sigma_m

    def contacts(self, separation_m: ArrayLike) -> NDArray[np.float64]:
        """Expected number of asperities in contact, n(d) (eq. 4; with MD adhesion, those whose
        contact radius is positive)."""
        h = self._h(separation_m)
        if self.summit_law is not None:
            h = h + self.summit_law.edge * self.summit_law.sphere.approach_unit_m / self.surface.sigma_m
        return self.summits * gaussian_integral(0.0, h, self._h_max)

    def attracted(self, separation_m: ArrayLike) -> NDArray[np.float64]:
        """Expected number of summits out of contact but within the adhesive range (0 without)."""
        law = self.summit_law
        if law is None:
            return np.zeros_like(self._h(separation_m))
        unit = law.sphere.approach_unit_m / self.surface.sigma_m
        h = self._h(separation_m)
        f_range, f_edge = (gaussian_integral(0.0, h + k * unit, self._h_max) for k in (-law.range, law.edge))
        return self.summits * (f_range - f_edge)

    def real_area_m2(self, separation_m: ArrayLike) -> NDArray[np.float64]:
        """Real contact area A_r(d) in m² (eq. 11, plus the MD correction with adhesion)."""
        h = self._h(separation_m)
        return self._area_scale * gaussian_integral(1.0, h, self._h_max) + self._corrections(h)[1]

    def load_n(self, separation_m: ArrayLike) -> NDArray[np.float64]:
        """Load in newtons the contact carries at separation d: P_r(d) (eq. 10) plus the MD
        adhesion correction (when w > 0); 0 above z_max."""
        return self._net_load(self._h(separation_m))

    def adhesion_n(self, separation_m: ArrayLike) -> NDArray[np.float64]:
        """Adhesive pull −ΔP(d) in newtons: Hertz load less net load (0 without adhesion)."""
        return -self._corrections(self._h(separation_m))[0]

    def _net_load(self, h: NDArray[np.float64]) -> NDArray[np.float64]:
        return self._load_scale * gaussian_integral(1.5, h, self._h_max) + self._corrections(h)[0]

    @property
    def max_load_n(self) -> float:
        """Largest load the model is valid for (separation μ − 8σ)."""
        return float(self._net_load(np.asarray(H_MIN)))

    def _initial_h(self, log_target: NDArray[np.float64]) -> NDArray[np.float64]:
        """Start for Newton: h at ``log_target`` from a table uniform in log F_{3/2} (~1e-7 off)."""
        if self._table is None:
            grid = np.linspace(H_MIN, self._h_max, _TABLE_POINTS)[:-1]
            logs = np.log(gaussian_integral(1.5, grid, self._h_max))[::-1]
            uniform = np.linspace(logs[0], logs[-1], _TABLE_POINTS)
            self._table = (uniform, np.interp(uniform, logs, grid[::-1]))
        logs, h = self._table
        position = (log_target - logs[0]) / (logs[1] - logs[0])
        index = np.clip(position.astype(np.int64), 0, logs.size - 2)
        frac = np.clip(position - index, 0.0, 1.0)
        return h[index] + frac * (h[index + 1] - h[index])

    def _adhesive_separation(self, target: NDArray[np.float64]) -> NDArray[np.float64]:
        """h of the largest separation where the GW-MD net load equals ``target`` (1-D)."""
        if self._scan is None:
            grid = np.arange(H_MIN, self._h_max + _SCAN_STEP, _SCAN_STEP)
            self._scan = grid, np.maximum.accumulate(self._net_load(grid)[::-1])
        grid, suffix_max = self._scan  # suffix_max[j] = max net load at h ≥ grid[-1 - j]
        j = np.searchsorted(suffix_max, target)  # first j with suffix max ≥ target
        k = np.clip(grid.size - 1 - j, 0, grid.size - 2)  # largest grid h with net load ≥ target

        def maugis(x: NDArray[np.float64], idx: NDArray[np.intp]) -> tuple[NDArray[np.float64], ...]:
            f32, f12 = gaussian_integrals((1.5, 0.5), x, self._h_max)
            extra, _, extra_slope = self._corrections(x)
            excess = self._load_scale * f32 + extra - target[idx]
            slope = -1.5 * self._load_scale * f12 + extra_slope
            return excess, -excess / slope

        lo, hi = grid[k], grid[k + 1]
        return _newton(0.5 * (lo + hi), lo, hi, maugis, _ACCEPT_STEP_LINEAR)

    def separation_m(self, load_n: ArrayLike) -> NDArray[np.float64]:
        """Separation d (m) at which the asperities carry ``load_n`` (N); vectorised.

        Solves P_r(d) = load by Newton on log F_{3/2}(h) (dF_n/dh = −n F_{n−1}),
        started from an interpolated inverse and kept inside its bracket.  With
        adhesion the net load need not be monotone in d: the part, lowered from above,
        stops at the *largest* d where it equals the weight (found on a grid of h, then
        safeguarded Newton in that cell).
        Raises :class:`InputError` for loads ≤ 0 or above :attr:`max_load_n`.
        """
        load = np.asarray(load_n, dtype=np.float64)
        if np.any(~np.isfinite(load)) or np.any(load <= 0):
            raise InputError("load", "must be positive and finite")
        if np.any(load > self.max_load_n):
            raise InputError(
                "load",
                f"{float(np.max(load)):.4g} N exceeds what this surface carries within the model "
                f"({self.max_load_n:.4g} N, separation μ − 8σ)",
            )
        log_target = np.log(load / self._load_scale).ravel()

        def hertz(x: NDArray[np.float64], idx: NDArray[np.intp]) -> tuple[NDArray[np.float64], ...]:
            f32, f12 = gaussian_integrals((1.5, 0.5), x, self._h_max)
            residual = np.log(f32) - log_target[idx]
            return residual, residual * f32 / (1.5 * f12)  # Δh = −g/g', g' = −1.5 F½/F3/2

        if self.summit_law is None:
            h = _newton(self._initial_h(log_target), H_MIN, self._h_max, hertz, _ACCEPT_STEP)
        if self.summit_law is not None:
            h = self._adhesive_separation(load.ravel())
        h = h.reshape(load.shape)
        return np.asarray(self.surface.mean_summit_height_m + self.surface.sigma_m * h)
