"""Compiled limit surface (numba, extra ``fast``; plain Python without it): :class:`.limit_surface.Patch`
on a part's parameter row (:func:`.planar_arrays.part_params`).

Rectangles by the closed form (:func:`.kernels.rectangle_integrals`), discs
over :data:`DISC_NODES` (unit disc: x, y, weight), scaled by their radius;
the gauge by BFGS.
"""

from __future__ import annotations

import math

import numpy as np

from feeder.plant.kernels import _jit, _jit_inline, rectangle_integrals
from feeder.plant.planar_arrays import AREA, DISC, HALF_A, HALF_B, JXX, JYY, POLAR, TAU_S

_SERIES_BELOW = 1e-3


def _unit_disc_nodes(radial: int = 48, angular: int = 96) -> np.ndarray:
    """(3, radial·angular): x, y, weight of the polar Gauss rule on the unit disc (as :class:`.Patch`)."""
    g, gw = np.polynomial.legendre.leggauss(radial)
    r = 0.5 * (g + 1)
    phi = 2 * np.pi * (np.arange(angular) + 0.5) / angular
    weight = np.outer(0.5 * gw * r, np.full(angular, 2 * np.pi / angular))
    return np.array([np.outer(r, np.cos(phi)).ravel(), np.outer(r, np.sin(phi)).ravel(), weight.ravel()])


DISC_NODES = _unit_disc_nodes()


# --- the limit surface (:class:`.limit_surface.Patch`) -----------------------------------------


@_jit_inline
def integrals(pp: np.ndarray, radius: float, nodes: np.ndarray, wx: float, wy: float,
              omega: float) -> tuple[float, float, float, float]:  # fmt: skip
    """:meth:`.Patch.integrals`: ∫v̂ dA, ∫ρ×v̂ dA, ∫|v| dA for the twist (w, ω), part frame."""
    speed = math.sqrt(wx * wx + wy * wy)  # glibc hypot: ~20 ns a call
    if speed == 0 and omega == 0:
        return 0.0, 0.0, 0.0, 0.0
    if abs(omega) * radius < _SERIES_BELOW * speed:
        ux, uy = wx / speed, wy / speed
        q = ux * ux * pp[JXX] + uy * uy * pp[JYY]
        area = pp[AREA]
        return area * ux, area * uy, omega * q / speed, speed * area + 0.5 * omega**2 * q / speed
    if pp[DISC] == 0:
        return rectangle_integrals(wx, wy, omega, pp[HALF_A], pp[HALF_B])
    r = pp[HALF_A]
    sx = sy = sm = sp = 0.0
    for i in range(nodes.shape[1]):
        x, y, weight = r * nodes[0, i], r * nodes[1, i], r * r * nodes[2, i]
        vx, vy = wx - omega * y, wy + omega * x
        v = math.sqrt(vx * vx + vy * vy)
        if v > 0:
            sx += weight * vx / v
            sy += weight * vy / v
            sm += weight * (x * vy - y * vx) / v
            sp += weight * v
    return sx, sy, sm, sp


@_jit
def _ratio(pp: np.ndarray, radius: float, nodes: np.ndarray, fx: float, fy: float, moment: float,
           scale: float, x: np.ndarray, grad: np.ndarray) -> float:  # fmt: skip
    """−W·ξ/∫|v_ξ|dA at the scaled twist x (ξ = (x₀, x₁, x₂/scale)); its gradient into ``grad``."""
    wx, wy, omega = x[0], x[1], x[2] / scale
    ux, uy, mu, power = integrals(pp, radius, nodes, wx, wy, omega)
    work = fx * wx + fy * wy + moment * omega
    grad[0] = -(fx - work * ux / power) / power
    grad[1] = -(fy - work * uy / power) / power
    grad[2] = -(moment - work * mu / power) / scale / power
    return -work / power


@_jit
def gauge(pp: np.ndarray, radius: float, nodes: np.ndarray, fx: float, fy: float,
          moment: float) -> tuple[float, float, float, float]:  # fmt: skip
    """:meth:`.Patch.gauge`: (g(W), ξ_x, ξ_y, ξ_ω), the maximum of W·ξ/∫|v_ξ|dA by BFGS."""
    force = math.hypot(fx, fy)
    if force == 0 and moment == 0:
        return 0.0, 0.0, 0.0, 0.0
    if moment == 0:
        return force / pp[AREA], fx / force, fy / force, 0.0
    if force == 0:
        return abs(moment) / pp[POLAR], 0.0, 0.0, math.copysign(1.0, moment)
    area, polar = pp[AREA], pp[POLAR]
    scale = polar / area
    x = np.array([fx / area**2, fy / area**2, scale * moment / polar**2])
    x /= math.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2)
    grad, trial, grad_trial = np.empty(3), np.empty(3), np.empty(3)
    f = _ratio(pp, radius, nodes, fx, fy, moment, scale, x, grad)
    h = np.eye(3)
    first = True
    for _ in range(200):
        if math.sqrt(grad @ grad) <= 1e-12 * abs(f):  # |x| stays ~1: a relative gradient
            break
        p = -(h @ grad)
        slope = p @ grad
        if slope >= 0:  # not a descent direction: restart from the steepest descent
            h = np.eye(3)
            p = -grad.copy()
            slope = p @ grad
        step = min(1.0, 0.1 / math.sqrt(p @ p)) if first else 1.0
        f_trial = f
        for _ in range(60):  # backtracking (Armijo)
            trial[:] = x + step * p
            f_trial = _ratio(pp, radius, nodes, fx, fy, moment, scale, trial, grad_trial)
            if f_trial <= f + 1e-4 * step * slope:
                break
            step *= 0.5
        if not f_trial < f:  # no decrease within rounding: converged
            break
        s = trial - x
        y = grad_trial - grad
        sy = s @ y
        if sy > 0:
            if first:
                h = np.eye(3) * (sy / (y @ y))
            rho = 1.0 / sy
            hy = h @ y
            h = h + ((sy + y @ hy) * rho * rho) * np.outer(s, s) - rho * (np.outer(hy, s) + np.outer(s, hy))
        first = False
        x[:] = trial
        grad[:] = grad_trial
        f = f_trial
    return -f, x[0], x[1], x[2] / scale


@_jit
def holds(pp: np.ndarray, radius: float, nodes: np.ndarray, fx: float, fy: float, moment: float) -> bool:
    """:meth:`.Patch.holds` at τ_s: the diamond, the cylinder, then the gauge."""
    stress = pp[TAU_S]
    f = math.hypot(fx, fy) / (stress * pp[AREA])
    m = abs(moment) / (stress * pp[POLAR])
    if f + m <= 1:
        return True
    if f > 1 or m > 1:
        return False
    return gauge(pp, radius, nodes, fx, fy, moment)[0] <= stress
