"""GW–Maugis–Dugdale: which summits pull.  A summit at approach δ = z − d is pulled from the
Dugdale range h₀ (δ = −h₀, the jump-in) until it touches (δ = δ_e); deeper ones are in
contact.  So contacts + attracted = every summit within h₀ of the flat, N·P(z > d − h₀), and
the attracted ones are N·∫ φ over d − h₀ < z < d + δ_e: both by mpmath here."""

from __future__ import annotations

from dataclasses import replace

import mpmath
import pytest
from scipy.stats import norm

from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.surface.parameters import DEFAULT_SURFACE

AREA = (300e-6) ** 2
WEIGHT_300 = 1.0285e-7


def summits_above(z: float, mu: float, sigma: float) -> mpmath.mpf:
    """P(summit height > z) for Gaussian heights (mean μ, std σ); z_max = μ + 10σ is immaterial."""
    return mpmath.erfc((mpmath.mpf(z) - mu) / (sigma * mpmath.sqrt(2))) / 2


@pytest.mark.parametrize("w", [0.005, 0.02, 0.1])
def test_attracted_summits_lie_within_the_dugdale_range(w: float) -> None:
    surface = replace(DEFAULT_SURFACE, adhesion_work_j_m2=w)
    h0, mu, sigma = surface.adhesion_range_m, surface.mean_summit_height_m, surface.sigma_m
    gw = GreenwoodWilliamson(surface, AREA)
    n = surface.summit_density_per_m2 * AREA
    for d in (float(gw.separation_m(WEIGHT_300)), mu + 2 * sigma, mu - sigma):
        attracted, touching = float(gw.attracted(d)), float(gw.contacts(d))
        within = float(n * summits_above(d - h0, mu, sigma))
        assert attracted + touching == pytest.approx(within, rel=1e-9)
        # the same band by quadrature of the height density, edge δ_e from the contact count
        edge = float(norm.isf(touching / n, mu, sigma))
        phi = lambda z: mpmath.npdf(z, mu, sigma)  # noqa: E731
        band = float(n * mpmath.quad(phi, [d - h0, edge]))
        assert attracted == pytest.approx(band, rel=1e-7)
        assert edge <= d  # summits touch only after being pulled in (δ_e ≤ 0)
