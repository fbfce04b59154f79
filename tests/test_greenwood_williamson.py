"""GW + Hertz against a slow, independent quad/brentq reference on randomised surfaces."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.errors import InputError
from feeder.surface.parameters import SurfaceParameters


def random_surface(rng: np.random.Generator) -> SurfaceParameters:
    sigma = rng.uniform(0.2e-9, 5e-9)
    mean = rng.uniform(0.0, 50e-9)
    return SurfaceParameters(
        sigma_m=sigma,
        summit_radius_m=rng.uniform(10e-9, 5e-6),
        summit_density_per_m2=rng.uniform(1e10, 1e15),
        mean_summit_height_m=mean,
        youngs_modulus_pa=rng.uniform(50e9, 400e9),
        poisson_ratio=rng.uniform(0.1, 0.4),
        z_max_m=mean + rng.uniform(4.0, 12.0) * sigma,
    )


class Reference:
    """Eqs. 4, 6, 8–11 integrated in z with scipy.integrate.quad (no shared code)."""

    def __init__(self, s: SurfaceParameters, area: float) -> None:
        self.s, self.n = s, s.summit_density_per_m2 * area
        e_star = s.youngs_modulus_pa / (2 * (1 - s.poisson_ratio**2))
        self.hertz = 4 / 3 * e_star * math.sqrt(s.summit_radius_m)

    def phi(self, z: float) -> float:
        u = (z - self.s.mean_summit_height_m) / self.s.sigma_m
        return math.exp(-0.5 * u * u) / (math.sqrt(2 * math.pi) * self.s.sigma_m)

    def integral(self, f, d: float) -> float:  # type: ignore[no-untyped-def]
        top = self.s.z_max
        if d >= top:
            return 0.0
        return quad(lambda z: f(z - d) * self.phi(z), d, top, epsabs=0, epsrel=1e-13, limit=200)[0]

    def load(self, d: float) -> float:
        return self.n * self.hertz * self.integral(lambda delta: delta**1.5, d)

    def area(self, d: float) -> float:
        return self.n * math.pi * self.s.summit_radius_m * self.integral(lambda delta: delta, d)

    def contacts(self, d: float) -> float:
        return self.n * self.integral(lambda delta: 1.0, d)

    def separation(self, load: float) -> float:
        lo = self.s.mean_summit_height_m - 6 * self.s.sigma_m
        return brentq(lambda d: self.load(d) - load, lo, self.s.z_max, xtol=1e-24, rtol=1e-14)


@pytest.mark.parametrize("seed", range(6))
def test_matches_quad_reference_on_random_surfaces(seed: int) -> None:
    rng = np.random.default_rng(seed)
    surface = random_surface(rng)
    area = rng.uniform(1e-9, 1e-6)
    gw, ref = GreenwoodWilliamson(surface, area), Reference(surface, area)
    heights = surface.mean_summit_height_m + surface.sigma_m * rng.uniform(-2.0, 3.5, 4)
    for d in heights:
        assert float(gw.load_n(d)) == pytest.approx(ref.load(d), rel=1e-9)
        assert float(gw.real_area_m2(d)) == pytest.approx(ref.area(d), rel=1e-9)
        assert float(gw.contacts(d)) == pytest.approx(ref.contacts(d), rel=1e-9)
    loads = gw.load_n(heights)
    solved = gw.separation_m(loads)
    for load, d in zip(loads, solved, strict=True):
        assert d == pytest.approx(ref.separation(load), rel=1e-10, abs=1e-6 * surface.sigma_m)


def test_separation_vectorised_round_trip_over_many_loads() -> None:
    surface = SurfaceParameters(0.5e-9, 50e-9, 1e14, 30e-9)
    gw = GreenwoodWilliamson(surface, 1e-7)
    loads = np.geomspace(1e-14, gw.max_load_n, 20000)
    d = gw.separation_m(loads)
    assert d.shape == loads.shape
    assert np.all(np.diff(d) < 0)  # more load → closer
    np.testing.assert_allclose(gw.load_n(d), loads, rtol=1e-11)


def test_nothing_touches_above_highest_summit() -> None:
    surface = SurfaceParameters(1e-9, 50e-9, 1e14, 0.0, z_max_m=4e-9)
    gw = GreenwoodWilliamson(surface, 1e-7)
    above = np.array([4e-9, 5e-9])
    assert np.all(gw.load_n(above) == 0) and np.all(gw.contacts(above) == 0)
    assert np.all(gw.real_area_m2(above) == 0)
    # truncation lowers the load compared with an untruncated surface at the same d
    untruncated = GreenwoodWilliamson(SurfaceParameters(1e-9, 50e-9, 1e14, 0.0), 1e-7)
    assert float(gw.load_n(2e-9)) < float(untruncated.load_n(2e-9))


@pytest.mark.parametrize("load", [0.0, -1e-9, float("nan")])
def test_rejects_non_positive_load(load: float) -> None:
    gw = GreenwoodWilliamson(SurfaceParameters(0.5e-9, 50e-9, 1e14, 30e-9), 1e-7)
    with pytest.raises(InputError, match="load"):
        gw.separation_m(load)


def test_rejects_load_the_surface_cannot_carry() -> None:
    gw = GreenwoodWilliamson(SurfaceParameters(0.5e-9, 50e-9, 1e14, 30e-9), 1e-7)
    with pytest.raises(InputError, match="exceeds what this surface carries"):
        gw.separation_m([1e-9, 10 * gw.max_load_n])
