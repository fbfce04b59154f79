"""Placements sampled summit by summit: the GW limit, the single-asperity Hertz limit, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feeder.contact.asperity_sampling import sample_contact
from feeder.contact.breakaway import contact
from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.parts import Part
from feeder.surface.parameters import DEFAULT_SURFACE, SurfaceParameters


@pytest.mark.parametrize(
    ("scale", "mean_tol", "spread_range"), [(100, 0.01, (0.015, 0.05)), (10, 0.05, (0.05, 0.15))]
)
def test_many_asperities_recover_gw(scale: int, mean_tol: float, spread_range: tuple) -> None:
    area, load = 9e-8 * scale, 1.0285e-7 * scale  # 300×300 pressure, n ≈ 3.2 × scale
    gw = GreenwoodWilliamson(DEFAULT_SURFACE, area)
    expected = float(gw.real_area_m2(gw.separation_m(load)))
    sampled = sample_contact(DEFAULT_SURFACE, area, load, placements=400)
    mean = float(np.mean(sampled.real_area_m2))
    assert mean == pytest.approx(expected, rel=mean_tol)
    spread = float(np.std(sampled.real_area_m2)) / mean
    assert spread_range[0] < spread < spread_range[1]  # shrinks like n^(-1/2)


def test_one_asperity_carries_everything_hertz_closed_form() -> None:
    # sparse, tall summits and a light load: the highest summit alone touches
    surface = SurfaceParameters(
        sigma_m=5e-9, summit_radius_m=1e-6, summit_density_per_m2=1e9, mean_summit_height_m=0.0
    )
    load = 1e-9
    sampled = sample_contact(surface, 1e-8, load, placements=300, seed=3)  # N = 10 summits
    single = sampled.contacts == 1
    assert single.mean() > 0.9
    e_star = surface.effective_modulus_pa
    delta = (3 * load / (4 * e_star * math.sqrt(surface.summit_radius_m))) ** (2 / 3)
    np.testing.assert_allclose(
        sampled.real_area_m2[single], math.pi * surface.summit_radius_m * delta, rtol=1e-9
    )


def test_deterministic_for_a_seed_and_band_in_contact_result() -> None:
    a = sample_contact(DEFAULT_SURFACE, 9e-8, 1.0285e-7, placements=200, seed=7)
    b = sample_contact(DEFAULT_SURFACE, 9e-8, 1.0285e-7, placements=200, seed=7)
    np.testing.assert_array_equal(a.real_area_m2, b.real_area_m2)
    result = contact(Part.parse("300x300x50"), placements=500)
    assert result.real_area_band_m2 is not None
    lo, hi = result.real_area_band_m2
    assert lo < result.real_area_sampled_mean_m2 < hi  # type: ignore[operator]
    assert any("placements" in w for w in result.warnings)
    assert contact(Part.parse("300x300x50")).real_area_band_m2 is None  # off by default
