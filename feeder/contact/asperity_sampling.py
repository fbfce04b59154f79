"""How much A_r scatters when only a few asperities touch: GW sampled summit by summit.

GW's integrals (eqs. 4–11) give the *expected* contact of infinitely many
summits.  Under a 300×300 µm part only ~3 summits touch, so the real area of
one placement of the part is a random variable.  Here each placement draws the
highest K summits of the N = η·A_n under the part, exactly, as order statistics
(N Poisson with mean η·A_n; tail probabilities p_k = Q(H) + (1 − Q(H))·Γ_k/Γ_{N+1},
Γ_k a sum of k unit exponentials, so z_k = μ + σ·Q⁻¹(p_k)); the separation is
then solved so that the Hertz loads Σ 4/3 E* R^½ (z_k − d)^{3/2} carry the weight,
and A_r = π R Σ (z_k − d).

With n equal asperities at a fixed load A_r ∝ n^{1/3}, so the spread is a
fraction of the Poisson spread of n; this module measures it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtri

from feeder.contact.gaussian_integrals import gaussian_integral
from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.errors import check_memory_budget
from feeder.surface.parameters import SurfaceParameters

DEFAULT_PLACEMENTS = 2000
_TOP_SUMMITS = 64
_BYTES_PER_HEIGHT = 48  # float64 heights, gaps and temporaries per summit drawn
"""Summits drawn per placement beyond 4× the GW contact count (more never touch)."""
_BISECTIONS = 80


@dataclass(frozen=True)
class SampledContact:
    """Real area and contacts over random placements (SI units).

    real_area_m2: every placement's A_r; contacts: asperities touching in each.
    """

    real_area_m2: np.ndarray
    contacts: np.ndarray

    def band_m2(self, coverage: float = 0.6827) -> tuple[float, float]:
        """Central interval of A_r holding ``coverage`` of the placements (default ±1σ-equivalent)."""
        lo, hi = np.quantile(self.real_area_m2, [(1 - coverage) / 2, (1 + coverage) / 2])
        return float(lo), float(hi)


def _top_heights(
    surface: SurfaceParameters, summits: float, count: int, placements: int, rng: np.random.Generator
) -> np.ndarray:
    """Heights (m) of the ``count`` highest summits under each placement, descending; −inf = none.

    The number of summits under the part is Poisson(``summits``); the k-th highest of N
    uniform tail probabilities is Γ_k/Γ_{N+1} exactly (Rényi's representation).
    """
    h_max = (surface.z_max - surface.mean_summit_height_m) / surface.sigma_m
    above_max = float(gaussian_integral(0.0, h_max))
    present = rng.poisson(summits, placements)
    gamma = np.cumsum(rng.exponential(size=(placements, count + 1)), axis=1)
    rows = np.arange(placements)
    beyond = np.maximum(present + 1 - (count + 1), 0)
    total = np.where(
        beyond > 0,
        gamma[:, -1] + rng.gamma(np.maximum(beyond, 1)),
        gamma[rows, np.minimum(present, count)],
    )
    tail = above_max + (1.0 - above_max) * gamma[:, :count] / total[:, None]
    heights = surface.mean_summit_height_m - surface.sigma_m * ndtri(tail)
    return np.where(np.arange(count) < present[:, None], heights, -np.inf)


def sample_contact(
    surface: SurfaceParameters,
    nominal_area_m2: float,
    load_n: float,
    placements: int = DEFAULT_PLACEMENTS,
    seed: int = 0,
) -> SampledContact:
    """A_r and contact count of ``placements`` random placements carrying ``load_n`` (N).

    Deterministic for a given ``seed``.  Raises ``ArithmeticError`` if the load
    needs more than the highest summits drawn (a load far above a part's weight),
    InputError (``placements``) if the draw would exceed the 2 GiB memory budget.
    """
    rng = np.random.default_rng(seed)
    gw = GreenwoodWilliamson(surface, nominal_area_m2)
    expected = float(gw.contacts(gw.separation_m(load_n)))
    summits = gw.summits
    count = int(min(max(summits, 1.0), _TOP_SUMMITS + math.ceil(4 * expected)))
    check_memory_budget("placements", placements * (count + 1) * _BYTES_PER_HEIGHT)
    z = _top_heights(surface, summits, count, placements, rng)
    hertz = 4.0 / 3.0 * surface.effective_modulus_pa * math.sqrt(surface.summit_radius_m)
    target = load_n / hertz  # Σ (z_k − d)^{3/2}, m^{3/2}

    def carried(d: np.ndarray) -> np.ndarray:
        return np.sum(np.maximum(z - d[:, None], 0.0) ** 1.5, axis=1)

    lowest = np.where(np.isfinite(z), z, np.inf).min(axis=1)
    lo, hi = lowest, z[:, 0].copy()  # carried(lo) ≥ target > carried(hi) = 0
    if np.any(~np.isfinite(lo)) or np.any(carried(lo) < target):
        raise ArithmeticError("the load needs more summits than were drawn (or there are none)")
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        high = carried(mid) > target
        lo, hi = np.where(high, mid, lo), np.where(high, hi, mid)
    d = 0.5 * (lo + hi)
    penetration = np.maximum(z - d[:, None], 0.0)
    return SampledContact(
        real_area_m2=math.pi * surface.summit_radius_m * penetration.sum(axis=1),
        contacts=np.count_nonzero(penetration, axis=1),
    )
