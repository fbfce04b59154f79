"""Maugis–Dugdale adhesion per summit in the GW model, attraction out of contact included (GW-MD).

Every summit of height z at separation d has the approach δ = z − d and obeys the
single-sphere Maugis–Dugdale law (:mod:`feeder.contact.adhesion_sphere`) in
Johnson's units (δ̄ = δ/δ₀, P̄ = P/(πwR), ā = a/a₀).  Its history is that of a part
lowered onto the support (approach):

- δ̄ < −h̄₀ (h̄₀ = 2/(πλ), the Dugdale range): no force;
- −h̄₀ ≤ δ̄ < δ̄_e: out of contact, pulled over a disc c̄ (MD's non-contact branch),
  c̄ = b + √(b² + 2(h̄₀ + δ̄)), b = 8λ/(3π), P̄ = −(πλ/2)c̄²; it jumps in at δ̄ = −h̄₀;
- δ̄ ≥ δ̄_e = −(4/3)λc̄_e: in contact, on the branch with the largest contact radius
  (the outer, stable branch; for JKR-like λ the summit jumps into contact at δ̄_e).

The load and area are GW's Hertz integrals (eqs. 10, 11) plus corrections

    ΔP(d) = N πwR ∫ [P̄(δ̄) − max(δ̄,0)^{3/2}] φ(z) dz,
    ΔA(d) = N π a₀² ∫ [ā(δ̄)² − max(δ̄,0)] φ(z) dz,

integrated by Gauss–Legendre panels in the branch parameters (c̄ out of contact, ā in
contact), with the Jacobians dδ̄/dc̄ = c̄ − b and dδ̄/dā from implicit differentiation
of Maugis' equation.  The nodes depend on the surface only, so one matrix product per
batch of separations gives ΔP, ΔA and dΔP/dd.  Summits in contact: n = N F₀(h_e) with
h_e = (d + δ₀δ̄_e − μ)/σ.  With w → 0 the corrections vanish (GW/Hertz is recovered).
Fuller & Tabor (1975) is the JKR limit (λ → ∞) of the same construction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy.special import roots_legendre

from feeder.contact.adhesion_sphere import SphereContact, _md_t, maugis_dugdale, md_edge_of_contact
from feeder.surface.parameters import SurfaceParameters

_NODES = 16
_GROWTH = 1.15
"""Contact-branch panels grow geometrically in ā by this factor ..."""
_PANEL_SIGMAS = 0.25
"""... and span at most this many σ of summit height (so φ is resolved)."""
_MAX_APPROACH = 1e7
"""Deepest δ̄ tabulated (w so small that δ₀ is tiny: deeper summits get no correction)."""


def _gauss(lo: NDArray[np.float64], hi: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """Gauss–Legendre nodes and weights on each panel [lo_i, hi_i], flattened."""
    x, w = roots_legendre(_NODES)
    half = 0.5 * (hi - lo)[:, None]
    return ((0.5 * (hi + lo))[:, None] + half * x).ravel(), (half * w).ravel()


def _md_slope(abar: NDArray[np.float64], lam: float) -> NDArray[np.float64]:
    """dδ̄/dā on MD's contact branch (implicit differentiation of Maugis' equation)."""
    t = _md_t(abar, lam)
    m = np.sqrt(1.0 + t * t)
    at = np.arctan(t)
    b1, b2 = t + (t * t - 1.0) * at, t * at - t * t / (m + 1.0)
    db1 = 2.0 * t * at + 2.0 * t * t / (m * m)
    db2 = at + t / (m * m) - t / m
    f_t = 0.5 * lam * abar**2 * db1 + 4.0 / 3.0 * lam**2 * abar * db2
    f_a = lam * abar * b1 + 4.0 / 3.0 * lam**2 * b2
    dt = -f_a / f_t
    return np.asarray(2.0 * abar - 4.0 / 3.0 * lam * (t + abar * dt))


def _approach_root(lam: float, lo: float, hi: float, target: float) -> float:
    """ā in [lo, hi] where δ̄(ā) crosses ``target`` upwards (δ̄ increasing there), by rounds of
    65-point grids (few vectorised MD solves) and a final linear interpolation."""
    for _ in range(6):
        grid = np.linspace(lo, hi, 65)
        excess = maugis_dugdale(np.maximum(grid, 1e-12), lam)[1] - target
        k = int(np.clip(np.searchsorted(excess, 0.0), 1, grid.size - 1))
        lo, hi = float(grid[k - 1]), float(grid[k])
        f_lo, f_hi = float(excess[k - 1]), float(excess[k])
    return lo if f_hi == f_lo else lo - f_lo * (hi - lo) / (f_hi - f_lo)


def _outer_start(lam: float, contact_approach: float) -> float:
    """ā where the outer (largest-radius) branch reaches ``contact_approach``: 0 if δ̄(ā)
    rises from ā = 0 and contact begins at the edge δ̄(0)."""
    grid = np.geomspace(1e-6, 50.0, 600)
    approach = maugis_dugdale(grid, lam)[1]
    k = int(np.argmin(approach))
    if k == 0 and approach[0] >= contact_approach - 1e-9 * abs(contact_approach):
        return 0.0
    return _approach_root(lam, float(grid[k]), float(grid[-1]), contact_approach)


@dataclass(frozen=True)
class SummitLaw:
    """Quadrature nodes of the per-summit MD corrections for one surface (Johnson's units).

    approach: δ̄_k; weight: quadrature weight × dδ̄/d(parameter); load: P̄ − max(δ̄,0)^{3/2};
    area: ā² − max(δ̄,0); edge: δ̄_e, where summits come into contact; range: h̄₀.
    """

    sphere: SphereContact
    approach: NDArray[np.float64]
    weight: NDArray[np.float64]
    load: NDArray[np.float64]
    area: NDArray[np.float64]
    edge: float
    range: float

    @classmethod
    @lru_cache(maxsize=32)
    def of(cls, surface: SurfaceParameters, deepest_m: float) -> SummitLaw:
        """Nodes covering approaches up to ``deepest_m`` (m); cached per surface."""
        sphere = SphereContact.from_range(
            surface.summit_radius_m,
            surface.effective_modulus_pa,
            surface.adhesion_work_j_m2,
            surface.adhesion_range_m,
        )
        lam, unit = sphere.tabor, sphere.approach_unit_m
        b, h0 = 8.0 * lam / (3.0 * math.pi), 2.0 / (math.pi * lam)
        c_edge = md_edge_of_contact(lam)
        # contact begins at δ̄_e = −(4/3)λc̄_e, or at the jump-in −h̄₀ if the jump lands in contact
        edge = max(-4.0 / 3.0 * lam * c_edge, -h0)
        panel = _PANEL_SIGMAS * surface.sigma_m / unit  # widest panel in δ̄
        # out of contact: c̄ from the jump-in 2b to the edge c̄_e (δ̄ from −h̄₀ to δ̄_e)
        pieces = max(1, math.ceil((edge + h0) / panel))
        c_lo, c_hi = 2.0 * b, max(c_edge, 2.0 * b)
        c_edges = np.sqrt(np.linspace((c_lo - b) ** 2, (c_hi - b) ** 2, pieces + 1)) + b  # uniform in δ̄
        c, wc = _gauss(c_edges[:-1], c_edges[1:])
        out_approach = 0.5 * c * c - b * c - h0
        out_weight = wc * (c - b)
        out_load = -0.5 * math.pi * lam * c * c
        # in contact: ā from the outer branch's start up to the deepest approach
        top = min(deepest_m / unit, _MAX_APPROACH)
        a_edges = _contact_edges(lam, _outer_start(lam, edge), top, panel)
        a, wa = _gauss(a_edges[:-1], a_edges[1:])
        p_bar, in_approach, _ = maugis_dugdale(a, lam)
        hertz = np.maximum(in_approach, 0.0)
        return cls(
            sphere=sphere,
            approach=np.concatenate([out_approach, in_approach]),
            weight=np.concatenate([out_weight, wa * _md_slope(a, lam)]),
            load=np.concatenate([out_load, p_bar - hertz**1.5]),
            area=np.concatenate([np.zeros_like(c), a * a - hertz]),
            edge=edge,
            range=h0,
        )


def _contact_edges(lam: float, start: float, top_approach: float, panel: float) -> NDArray[np.float64]:
    """Panel edges in ā: geometric growth, a break where δ̄ = 0 (Hertz's kink), and no panel
    wider than ``panel`` in δ̄."""
    first = max(start, 1e-3) if start > 0 else 0.0
    # δ̄ < ā², so the top lies below √(top) + a margin that covers the adhesive offset
    reach = math.sqrt(top_approach) + 4.0 * lam + 4.0
    count = math.ceil(math.log1p((reach - first) * (_GROWTH - 1.0) / 0.02) / math.log(_GROWTH)) + 1
    grid = first + 0.02 * (_GROWTH ** np.arange(count + 1) - 1.0) / (_GROWTH - 1.0)
    approach = maugis_dugdale(np.maximum(grid, 1e-12), lam)[1]
    last = int(np.searchsorted(approach, top_approach))  # δ̄ increases on the outer branch
    top = _approach_root(lam, float(grid[last - 1]), float(grid[last]), top_approach)
    coarse = [*grid[:last], top]
    crossing = int(np.searchsorted(approach, 0.0))
    if 0 < crossing < last:
        coarse.append(_approach_root(lam, float(grid[crossing - 1]), float(grid[crossing]), 0.0))
    edges_coarse = np.unique(np.asarray(coarse))
    at_edges = maugis_dugdale(np.maximum(edges_coarse, 1e-12), lam)[1]
    edges = [edges_coarse[0]]
    for i in range(edges_coarse.size - 1):
        pieces = max(1, math.ceil((at_edges[i + 1] - at_edges[i]) / panel))
        edges.extend(np.linspace(edges_coarse[i], edges_coarse[i + 1], pieces + 1)[1:])
    return np.asarray(edges)
