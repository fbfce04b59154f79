"""Greenwood–Williamson multi-asperity contact with Hertzian asperities (paper eqs. 4–11).

An equivalent rough surface (summit heights Gaussian, mean μ, std σ, radius R,
density η) against a smooth plane at separation d.  With h = (d − μ)/σ and the
highest summit H = (z_max − μ)/σ:

    n(d)   = N F_0(h, H)                              (eq. 4)
    A_r(d) = π N R σ F_1(h, H)                        (eqs. 5, 9, 11)
    P_r(d) = 4/3 N E* R^½ σ^{3/2} F_{3/2}(h, H)       (eqs. 6, 8, 10)

N = η A_n.  All of it vectorised over d (or over loads for the inverse).

With a work of adhesion w > 0 (``SurfaceParameters.adhesion_work_j_m2``) each
contacting summit also pulls with the DMT force 2πwR, so the load the contact
carries is P_r(d) − 2πwR·n(d); the paper leaves adhesion out (its future work).
That net load is strictly decreasing in d wherever it is positive (F_{3/2}/F_0
decreases with h), so the separation for a given weight is unique.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from feeder.contact.gaussian_integrals import H_MIN, gaussian_integral, gaussian_integrals
from feeder.errors import InputError
from feeder.surface.parameters import SurfaceParameters

_TABLE_POINTS = 40001
_ACCEPT_STEP = 1e-6
_ACCEPT_STEP_LINEAR = 1e-9
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
            4.0 / 3.0 * self.summits * s.effective_modulus_pa
            * math.sqrt(s.summit_radius_m) * s.sigma_m**1.5
        )
        self._area_scale = math.pi * self.summits * s.summit_radius_m * s.sigma_m
        self._adhesion_scale = 2.0 * math.pi * s.adhesion_work_j_m2 * s.summit_radius_m * self.summits
        self._table: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None

    def _h(self, separation_m: ArrayLike) -> NDArray[np.float64]:
        d = np.asarray(separation_m, dtype=np.float64)
        return (d - self.surface.mean_summit_height_m) / self.surface.sigma_m

    def contacts(self, separation_m: ArrayLike) -> NDArray[np.float64]:
        """Expected number of asperities in contact, n(d) (eq. 4)."""
        return self.summits * gaussian_integral(0.0, self._h(separation_m), self._h_max)

    def real_area_m2(self, separation_m: ArrayLike) -> NDArray[np.float64]:
        """Real contact area A_r(d) in m² (eq. 11)."""
        return self._area_scale * gaussian_integral(1.0, self._h(separation_m), self._h_max)

    def load_n(self, separation_m: ArrayLike) -> NDArray[np.float64]:
        """Load in newtons the contact carries at separation d: P_r(d) (eq. 10) less the DMT
        adhesion (when w > 0); 0 above z_max."""
        return self._net_load(self._h(separation_m))

    def adhesion_n(self, separation_m: ArrayLike) -> NDArray[np.float64]:
        """DMT adhesive pull 2πwR·n(d) in newtons (0 without adhesion)."""
        return self._adhesion_scale * gaussian_integral(0.0, self._h(separation_m), self._h_max)

    def _net_load(self, h: NDArray[np.float64]) -> NDArray[np.float64]:
        f32, f0 = gaussian_integrals((1.5, 0.0), h, self._h_max)
        return self._load_scale * f32 - self._adhesion_scale * f0

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

    def separation_m(self, load_n: ArrayLike) -> NDArray[np.float64]:
        """Separation d (m) at which the asperities carry ``load_n`` (N); vectorised.

        Solves P_r(d) = load by Newton on log F_{3/2}(h) (dF_n/dh = −n F_{n−1}),
        started from an interpolated inverse and kept inside its bracket; with
        adhesion, a second Newton from there on the net load (DMT).
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

        h = _newton(self._initial_h(log_target), H_MIN, self._h_max, hertz, _ACCEPT_STEP)
        if self._adhesion_scale > 0:  # the Hertz-only h has too little load: an upper bracket
            target = load.ravel()

            def dmt(x: NDArray[np.float64], idx: NDArray[np.intp]) -> tuple[NDArray[np.float64], ...]:
                f32, f12, f0 = gaussian_integrals((1.5, 0.5, 0.0), x, self._h_max)
                excess = self._load_scale * f32 - self._adhesion_scale * f0 - target[idx]
                slope = (-1.5 * self._load_scale * f12
                         + self._adhesion_scale * np.exp(-0.5 * x * x) / math.sqrt(2 * math.pi))
                return excess, -excess / slope

            h = _newton(h.copy(), H_MIN, h, dmt, _ACCEPT_STEP_LINEAR)
        h = h.reshape(load.shape)
        return np.asarray(self.surface.mean_summit_height_m + self.surface.sigma_m * h)
