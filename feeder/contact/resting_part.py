"""Where a rigid part comes to rest on the summits under it: tilt included, ≥ 3 contacts.

GW's integrals (eqs. 4–11) are the mean field of infinitely many summits.  Under a
300×300 µm part only a few touch, and a rigid part does not sink level onto them:
lowered onto the support it touches the highest summit, tips about it, and comes to
rest on (at least) three summits whose triangle holds the projection of its centre
of mass.  Here each placement draws the summits under the footprint (a Poisson field
of density η, heights Gaussian N(μ, σ) cut at z_max, positions uniform over the
lands of the support) and finds the rest of the part's plane

    z(x, y) = d + αx + βy

with Hertzian summits P_i = K δ_i^{3/2}, K = 4/3 E* R^½, δ_i = z_i − z(x_i, y_i) (eq. 6):
force and moment balance Σ P_i = W, Σ P_i x_i = 0, Σ P_i y_i = 0 about the centre
of mass.  Those three equations are the stationarity of the convex energy

    U(d, α, β) = W d + Σ 2/5 K δ_i^{5/2}

(weight times the height of the centre of mass plus the elastic energy), so the rest
is unique and a damped Newton (Levenberg–Marquardt, every step lowering U) finds it
from the level start.  A_r = π R Σ δ_i (eq. 5).  With exactly three contacts the
loads are statically determinate: P_i = W·b_i with b_i the barycentric coordinates of
the centre of mass in the contact triangle, whatever the heights.

Only the highest summits are drawn (order statistics, as in
:mod:`feeder.contact.asperity_sampling`); the draw is proven sufficient afterwards:
the plane at rest must lie above the lowest summit drawn over the whole footprint,
else the placement is drawn again with more summits.  The positions of the summits
are independent of their heights (a marked Poisson field), so they are uniform.

Parameters come from a :class:`SurfaceParameters` (the embedded surface or one made
from measured scans by ``feeder surface --out``).  Without adhesion only: the
Maugis–Dugdale summits of :mod:`feeder.contact.gw_maugis_dugdale` make U non-convex.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from feeder.contact.asperity_sampling import _top_heights
from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.errors import InputError, check_memory_budget
from feeder.parts import FLAT, Part, Support
from feeder.surface.parameters import SurfaceParameters

DEFAULT_PLACEMENTS = 2000
_EXTRA_SUMMITS = 48
"""Summits drawn beyond 4× GW's contact count (the draw is checked and grown if short)."""
_BYTES_PER_SUMMIT = 160  # heights, positions, penetrations and temporaries per summit drawn
_MAX_ITERATIONS = 400
_TOLERANCE = 1e-11
"""Relative residual of force and moment balance at rest."""


@dataclass(frozen=True)
class RestingSample:
    """Rest of a rigid part over random placements (SI units), one entry per placement.

    real_area_m2: A_r; contacts: summits touching; tilt_rad: angle of the part's plane;
    separation_m: height of the plane under the centre of mass (GW's d for a level part);
    largest_share: the largest fraction of the weight one summit carries.
    """

    real_area_m2: NDArray[np.float64]
    contacts: NDArray[np.int64]
    tilt_rad: NDArray[np.float64]
    separation_m: NDArray[np.float64]
    largest_share: NDArray[np.float64]
    gw_real_area_m2: float
    """GW's mean-field A_r for the same part, surface and load."""
    gw_contacts: float

    def band_m2(self, coverage: float = 0.6827) -> tuple[float, float]:
        """Central interval of A_r holding ``coverage`` of the placements (default ±1σ-equivalent)."""
        lo, hi = np.quantile(self.real_area_m2, [(1 - coverage) / 2, (1 + coverage) / 2])
        return float(lo), float(hi)


def _positions(
    count: int, placements: int, part: Part, support: Support, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Summit positions (X, Y) scaled to the half sides (−1…1), uniform over the support's lands.

    Grooved: lands of ``land_width_m`` every ``groove_period_m`` along x, at a random phase
    per placement (wrapped into the footprint).
    """
    half_x = part.length_m / 2
    y = rng.uniform(-1.0, 1.0, (placements, count))
    if support.kind == "flat":
        return rng.uniform(-1.0, 1.0, (placements, count)), y
    on_land = rng.uniform(0.0, part.length_m * support.area_fraction, (placements, count))
    phase = rng.uniform(0.0, support.groove_period_m, (placements, 1))
    x = np.floor(on_land / support.land_width_m) * support.groove_period_m
    x = np.mod(x + np.mod(on_land, support.land_width_m) + phase, part.length_m)
    return x / half_x - 1.0, y


def _rigid_rest(
    z: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Rest of a rigid part: plane (c, a, b) and its three contacts, per placement (rows).

    The lowest centre of mass over planes above every summit, a 3-variable linear
    program, solved by pivoting as the part itself does: level on the highest summit,
    tip about it until a second touches, about their line until a third touches; if
    the centre of mass (origin) is outside that triangle, lift the vertex across the
    edge from it and tip about that edge again.
    """
    rows, summits = z.shape
    row = np.arange(rows)
    first = np.argmax(z, axis=1)
    p = np.stack([z[row, first], np.zeros(rows), np.zeros(rows)], axis=1)
    touching = np.stack([first, first, first], axis=1)  # contact indices; count says how many are real
    count = np.ones(rows, dtype=np.intp)
    for _ in range(4 * summits + 8):
        rx, ry = x[row[:, None], touching], y[row[:, None], touching]
        if np.any(count == 3):  # centre of mass inside the triangle? else drop the vertex across
            ux, uy = rx[:, 1] - rx[:, 0], ry[:, 1] - ry[:, 0]
            vx, vy = rx[:, 2] - rx[:, 0], ry[:, 2] - ry[:, 0]
            det = ux * vy - uy * vx
            b1 = (-rx[:, 0] * vy + ry[:, 0] * vx) / det
            b2 = (-ux * ry[:, 0] + uy * rx[:, 0]) / det
            bary = np.stack([1.0 - b1 - b2, b1, b2], axis=1)
            inside = np.all(bary >= 0, axis=1) & (count == 3)
            drop = np.argmin(bary, axis=1)
            moving = (count == 3) & ~inside
            kept = np.array([[1, 2], [0, 2], [0, 1]])[drop]
            touching[moving, :2] = touching[row[:, None], kept][moving]
            count[moving] = 2
            if not np.any(~inside):
                return p, touching
        else:
            inside = np.zeros(rows, dtype=bool)
        rx, ry = x[row[:, None], touching], y[row[:, None], touching]
        # tipping direction: plane change (r − r0)·n, n pointing away from the centre of mass
        nx, ny = rx[:, 0].copy(), ry[:, 0].copy()  # one contact: along r0
        two = count == 2
        ex, ey = rx[:, 1] - rx[:, 0], ry[:, 1] - ry[:, 0]
        nx[two], ny[two] = -ey[two], ex[two]
        flip = two & (nx * rx[:, 0] + ny * ry[:, 0] < 0)
        nx[flip], ny[flip] = -nx[flip], -ny[flip]
        norm = np.hypot(nx, ny)
        nx, ny = nx / norm, ny / norm
        dp = np.stack([-(nx * rx[:, 0] + ny * ry[:, 0]), nx, ny], axis=1)
        change = dp[:, :1] + dp[:, 1:2] * x + dp[:, 2:3] * y
        gap = p[:, :1] + p[:, 1:2] * x + p[:, 2:3] * y - z
        falling = change < -1e-12 * (np.abs(dp[:, :1]) + 1.0)
        falling[row[:, None], touching] = False
        s = np.where(falling, np.maximum(gap, 0.0) / np.where(falling, -change, 1.0), np.inf)
        hit = np.argmin(s, axis=1)
        step = s[row, hit]
        tipping = ~inside
        if np.any(tipping & ~np.isfinite(step)):
            raise ArithmeticError("resting part: the centre of mass lies outside the summits drawn")
        p[tipping] += step[tipping, None] * dp[tipping]
        touching[tipping, count[tipping]] = hit[tipping]
        count[tipping] += 1
    raise ArithmeticError("resting part: pivoting did not reach a rest")


def _rest(
    zeta: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64], weight: float
) -> NDArray[np.float64]:
    """Plane (c, a, b) at rest, ζ_plane = c + aX + bY, for each placement (rows), scaled units.

    ζ: summit heights (−inf = absent) in σ from μ; weight: W/(Kσ^{3/2}).  Minimises
    U = weight·c + Σ 2/5 δ^{5/2} (δ = ζ − ζ_plane) by damped Newton, started from the
    rigid rest lowered so its three contacts carry the weight by the lever rule.
    """
    z = np.where(np.isfinite(zeta), zeta, -1e300)
    rows = z.shape[0]
    row = np.arange(rows)[:, None]

    def penetration(p: NDArray[np.float64], idx: NDArray[np.intp]) -> NDArray[np.float64]:
        return np.maximum(z[idx] - (p[:, :1] + p[:, 1:2] * x[idx] + p[:, 2:3] * y[idx]), 0.0)

    def energy(p: NDArray[np.float64], idx: NDArray[np.intp]) -> NDArray[np.float64]:
        return weight * p[:, 0] + 0.4 * np.sum(penetration(p, idx) ** 2.5, axis=1)

    _, touching = _rigid_rest(z, x, y)
    corners = np.stack([np.ones((rows, 3)), x[row, touching], y[row, touching]], axis=-1)
    unit_load = np.broadcast_to(np.array([1.0, 0.0, 0.0])[:, None], (rows, 3, 1))
    share = np.linalg.solve(np.swapaxes(corners, 1, 2), unit_load)[:, :, 0]  # barycentric coordinates
    sunk = z[row, touching] - (weight * np.maximum(share, 0.0)) ** (2 / 3)
    p = np.asarray(np.linalg.solve(corners, sunk[:, :, None])[:, :, 0], dtype=np.float64)  # the plane
    damping = np.full(rows, 1e-9)
    active = np.arange(rows)
    current = energy(p, active)
    for _ in range(_MAX_ITERATIONS):
        delta = penetration(p[active], active)
        xa, ya = x[active], y[active]
        force, stiffness = delta**1.5, 1.5 * np.sqrt(delta)
        gradient = np.stack(
            [weight - force.sum(axis=1), -(force * xa).sum(axis=1), -(force * ya).sum(axis=1)], axis=1
        )
        kx, ky = stiffness * xa, stiffness * ya
        sums = [stiffness.sum(axis=1), kx.sum(axis=1), ky.sum(axis=1)]
        sums += [(kx * xa).sum(axis=1), (kx * ya).sum(axis=1), (ky * ya).sum(axis=1)]
        hessian = np.stack([sums[0], sums[1], sums[2], sums[1], sums[3], sums[4], sums[2], sums[4], sums[5]])
        hessian = hessian.T.reshape(-1, 3, 3)
        done = np.max(np.abs(gradient), axis=1) <= _TOLERANCE * weight
        diagonal = np.diagonal(hessian, axis1=1, axis2=2)
        scale = diagonal + 1e-12 * np.max(diagonal, axis=1, keepdims=True) + 1e-300
        shifted = hessian + (damping[active, None] * scale)[:, :, None] * np.eye(3)
        step = np.asarray(-np.linalg.solve(shifted, gradient[:, :, None])[:, :, 0], dtype=np.float64)
        trial = p[active] + step
        trial_energy = energy(trial, active)
        slack = 1e-13 * (np.abs(current[active]) + weight)  # rounding of U near the minimum
        better = (trial_energy <= current[active] + slack) & ~done
        p[active[better]] = trial[better]
        current[active[better]] = trial_energy[better]
        damping[active] = np.where(better, np.maximum(damping[active] * 0.2, 1e-12), damping[active] * 8.0)
        if np.any(damping[active] > 1e30):
            raise ArithmeticError("resting part: no step lowers the energy before force balance")
        active = active[~done]
        if active.size == 0:
            return p
    raise ArithmeticError("resting part: damped Newton did not converge")


def _enough(zeta: NDArray[np.float64], plane: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Per placement: no summit left out (below the lowest drawn) can reach the plane at rest."""
    complete = np.isinf(zeta[:, -1])  # every summit under the part was drawn
    lowest_drawn = np.min(np.where(np.isfinite(zeta), zeta, np.inf), axis=1)
    lowest_plane = plane[:, 0] - np.abs(plane[:, 1]) - np.abs(plane[:, 2])  # at a corner
    return np.asarray(complete | (lowest_plane > lowest_drawn))


def rest_part(
    surface: SurfaceParameters,
    part: Part,
    support: Support = FLAT,
    load_n: float | None = None,
    placements: int = DEFAULT_PLACEMENTS,
    seed: int = 0,
) -> RestingSample:
    """Rest of ``part`` (its weight, or ``load_n`` N) on ``support`` over ``placements`` placements.

    Deterministic for a given ``seed``.  Raises InputError for a surface with adhesion
    (``adhesion_work_j_m2``), for a draw beyond the 2 GiB memory budget (``placements``)
    and ArithmeticError if the solver does not converge.
    """
    if surface.adhesion_work_j_m2:
        raise InputError("adhesion_work_j_m2", "the resting-part sampler is Hertz-only (w must be 0)")
    load = part.weight_n if load_n is None else load_n
    gw = GreenwoodWilliamson(surface, support.nominal_area_m2(part))
    gw_d = float(gw.separation_m(load))
    gw_contacts = float(gw.contacts(gw_d))
    stiffness = 4.0 / 3.0 * surface.effective_modulus_pa * math.sqrt(surface.summit_radius_m)
    weight = load / (stiffness * surface.sigma_m**1.5)
    rng = np.random.default_rng(seed)
    first = int(min(max(gw.summits, 3.0), _EXTRA_SUMMITS + math.ceil(4 * gw_contacts)))
    drawn = 2 * first + 4 * _EXTRA_SUMMITS
    while True:
        check_memory_budget("placements", placements * (drawn + 1) * _BYTES_PER_SUMMIT)
        heights = _top_heights(surface, gw.summits, drawn, placements, rng)
        zeta = (heights - surface.mean_summit_height_m) / surface.sigma_m
        x, y = _positions(drawn, placements, part, support, rng)
        if np.any(np.isfinite(zeta).sum(axis=1) < 3):
            raise InputError("--part", "fewer than three summits under the part: it cannot rest")
        plane = np.empty((placements, 3))
        todo, used = np.arange(placements), first
        while todo.size:  # solve on the highest `used` summits; more where that was not enough
            plane[todo] = _rest(zeta[todo, :used], x[todo, :used], y[todo, :used], weight)
            todo = todo[~_enough(zeta[todo, :used], plane[todo])]
            if used == drawn:
                break
            used = min(2 * used, drawn)
        if todo.size == 0:
            break
        drawn *= 4  # a placement might touch a summit not drawn: draw again, more
    delta = np.maximum(zeta - (plane[:, :1] + plane[:, 1:2] * x + plane[:, 2:3] * y), 0.0)
    loads = delta**1.5
    sigma = surface.sigma_m
    tilt = np.hypot(plane[:, 1] * sigma / (part.length_m / 2), plane[:, 2] * sigma / (part.width_m / 2))
    return RestingSample(
        real_area_m2=math.pi * surface.summit_radius_m * sigma * delta.sum(axis=1),
        contacts=np.count_nonzero(delta, axis=1),
        tilt_rad=np.arctan(tilt),
        separation_m=surface.mean_summit_height_m + sigma * plane[:, 0],
        largest_share=loads.max(axis=1) / loads.sum(axis=1),
        gw_real_area_m2=float(gw.real_area_m2(gw_d)),
        gw_contacts=gw_contacts,
    )
