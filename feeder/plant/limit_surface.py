"""Coulomb friction integrated over a part's contact patch: the limit surface (DESIGN §9).

A rigid part slides on the plate with the relative twist (w, ω): the velocity of
its centre relative to the plate point under it, w (m/s), and its angular
velocity relative to the plate, ω (rad/s).  The point ρ of the patch (part
frame, origin at the part's centre) slides at v(ρ) = w + ω ẑ×ρ.  With a uniform
friction stress τ over the patch (uniform pressure, DESIGN §9) the friction
acting on the part is

    F = −τ ∫ v̂ dA,   M = −τ ∫ ρ × v̂ dA   (about the centre),

and the dissipated power is τ ∫ |v| dA, the support function of the limit
surface: the set of (F, M) the contact holds without slipping is
{W : W·ξ ≤ τ ∫|v_ξ| dA for every twist ξ} (Goyal, Ruina & Papadopoulos 1991).
Its gauge g(W) = max_ξ W·ξ / ∫|v_ξ| dA says how far W is from the surface:
the part sticks under the wrench W while g(W) ≤ τ.

Rectangles are integrated in closed form about the instantaneous centre of
rotation ρ_c = ẑ×w/ω (corner functions, checked against quadrature in the
tests); when ρ_c lies far outside the patch (|ω|·r_patch < 10⁻³|w|) a series in
ω/|w| to first order replaces them (relative error ≲ 10⁻⁶; exact for ω = 0).
Discs use a polar Gauss quadrature (relative error ≲ 2·10⁻⁴ when ρ_c lies on the
disc, 1.3·10⁻⁴ against dblquad on a 300 µm disc; exact by symmetry at the centre and for pure translation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.optimize import minimize

from feeder.errors import InputError
from feeder.plant import kernels

SHAPES = ("rectangle", "disc")
_SERIES_BELOW = 1e-3
_DISC_RADIAL, _DISC_ANGULAR = 48, 96

Integrals = tuple[float, float, float, float]
"""(∫v̂_x dA, ∫v̂_y dA, ∫ρ×v̂ dA, ∫|v| dA) in m², m², m³, m³/s."""


@dataclass(frozen=True)
class Patch:
    """Nominal contact patch of a part, centred on it, axes along the part's.

    rectangle: length_m along the part's first axis, width_m across it;
    disc: diameter length_m (width_m equal to it).
    """

    shape: str
    length_m: float
    width_m: float

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise InputError("shape", f"expected one of {', '.join(SHAPES)}, got {self.shape!r}")
        for name in ("length_m", "width_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(name, f"must be a positive number, got {value!r}")
        if self.shape == "disc" and self.width_m != self.length_m:
            raise InputError("width_m", "a disc's width is its diameter")

    @property
    def area_m2(self) -> float:
        if self.shape == "disc":
            return math.pi * self.length_m**2 / 4
        return self.length_m * self.width_m

    @property
    def radius_m(self) -> float:
        """Distance from the centre to the farthest patch point."""
        return 0.5 * math.hypot(self.length_m, self.width_m) if self.shape == "rectangle" else (
            0.5 * self.length_m)  # fmt: skip

    @cached_property
    def polar_m3(self) -> float:
        """∫|ρ| dA: the moment a unit stress holds against a pure turn about the centre."""
        if self.shape == "disc":
            return 2 * math.pi * (0.5 * self.length_m) ** 3 / 3
        a, b = 0.5 * self.length_m, 0.5 * self.width_m
        return kernels.box_r(-a, a, -b, b)

    @cached_property
    def second_moments_m4(self) -> tuple[float, float]:
        """(∫x² dA, ∫y² dA) in the part frame."""
        if self.shape == "disc":
            j = math.pi * (0.5 * self.length_m) ** 4 / 4
            return j, j
        a, b = self.length_m, self.width_m
        return a**3 * b / 12, a * b**3 / 12

    @cached_property
    def _disc_nodes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        radius = 0.5 * self.length_m
        g, gw = np.polynomial.legendre.leggauss(_DISC_RADIAL)
        r = 0.5 * radius * (g + 1)
        phi = 2 * np.pi * (np.arange(_DISC_ANGULAR) + 0.5) / _DISC_ANGULAR
        weight = np.outer(0.5 * radius * gw * r, np.full(_DISC_ANGULAR, 2 * np.pi / _DISC_ANGULAR))
        return (np.outer(r, np.cos(phi)).ravel(), np.outer(r, np.sin(phi)).ravel(), weight.ravel())

    def integrals(self, wx: float, wy: float, omega: float) -> Integrals:
        """∫v̂ dA, ∫ρ×v̂ dA and ∫|v| dA for the slip twist (w, ω), part frame; zeros at rest."""
        speed = math.hypot(wx, wy)
        if speed == 0 and omega == 0:
            return 0.0, 0.0, 0.0, 0.0
        if abs(omega) * self.radius_m < _SERIES_BELOW * speed:
            ux, uy = wx / speed, wy / speed
            jxx, jyy = self.second_moments_m4
            q = ux * ux * jxx + uy * uy * jyy  # ∫(ρ·ŵ)² dA
            area = self.area_m2
            return area * ux, area * uy, omega * q / speed, speed * area + 0.5 * omega**2 * q / speed
        if self.shape == "disc":
            return self._disc(wx, wy, omega)
        return kernels.rectangle_integrals(wx, wy, omega, 0.5 * self.length_m, 0.5 * self.width_m)

    def _disc(self, wx: float, wy: float, omega: float) -> Integrals:
        x, y, weight = self._disc_nodes
        vx, vy = wx - omega * y, wy + omega * x
        speed = np.hypot(vx, vy)
        safe = np.where(speed > 0, speed, 1.0)
        ux, uy = np.where(speed > 0, vx / safe, 0.0), np.where(speed > 0, vy / safe, 0.0)
        return (float(weight @ ux), float(weight @ uy), float(weight @ (x * uy - y * ux)),
                float(weight @ speed))  # fmt: skip

    def gauge(self, fx: float, fy: float, moment: float) -> tuple[float, tuple[float, float, float]]:
        """g(W) = max_ξ W·ξ/∫|v_ξ| dA for the wrench W = (F, M) (part frame), and the maximising ξ.

        g is the friction stress (Pa) needed to hold W: the part sticks iff
        g ≤ τ_s.  ξ = (w_x, w_y, ω) is the slip twist that W drives at
        breakaway (unnormalised).  Pure force and pure moment are exact
        (|F|/A, |M|/∫|ρ|dA); combined wrenches are maximised numerically (BFGS).
        """
        force = math.hypot(fx, fy)
        if force == 0 and moment == 0:
            return 0.0, (0.0, 0.0, 0.0)
        if moment == 0:
            return force / self.area_m2, (fx / force, fy / force, 0.0)
        if force == 0:
            return abs(moment) / self.polar_m3, (0.0, 0.0, math.copysign(1.0, moment))
        scale = self.polar_m3 / self.area_m2  # a length: ω·scale is a speed

        def negative_ratio(x: np.ndarray) -> tuple[float, np.ndarray]:
            wx, wy, omega = float(x[0]), float(x[1]), float(x[2]) / scale
            ux, uy, mu, power = self.integrals(wx, wy, omega)
            work = fx * wx + fy * wy + moment * omega
            grad = np.array([fx - work * ux / power, fy - work * uy / power,
                             (moment - work * mu / power) / scale]) / power  # fmt: skip
            return -work / power, -grad

        area, polar = self.area_m2, self.polar_m3
        start = np.array([fx / area**2, fy / area**2, scale * moment / polar**2])
        best = minimize(negative_ratio, start / np.linalg.norm(start), jac=True, method="BFGS",
                        options={"gtol": 1e-13, "maxiter": 200})  # fmt: skip
        x = best.x
        return -float(best.fun), (float(x[0]), float(x[1]), float(x[2]) / scale)

    def holds(self, fx: float, fy: float, moment: float, stress_pa: float) -> bool:
        """True if a friction stress ``stress_pa`` holds the wrench (F, M) without slipping.

        Cheap bounds first: the limit surface contains the diamond
        |F|/F₀ + |M|/M₀ ≤ 1 and lies inside the cylinder |F| ≤ F₀, |M| ≤ M₀
        (F₀ = τA, M₀ = τ∫|ρ|dA); the gauge decides in between.
        """
        f = math.hypot(fx, fy) / (stress_pa * self.area_m2)
        m = abs(moment) / (stress_pa * self.polar_m3)
        if f + m <= 1:
            return True
        if f > 1 or m > 1:
            return False
        return self.gauge(fx, fy, moment)[0] <= stress_pa
