"""The rigid part at rest on its summits: the lever rule, the LP, force balance, the draw, the GW trend."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linprog, minimize
from scipy.spatial import Delaunay

from feeder.contact.asperity_sampling import sample_contact
from feeder.contact.resting_part import _rest, _rigid_rest, rest_part
from feeder.parts import GROOVED, Part
from feeder.surface.parameters import DEFAULT_SURFACE


def _random_field(seed: int, rows: int = 40, summits: int = 30):
    rng = np.random.default_rng(seed)
    z = np.sort(rng.normal(size=(rows, summits)), axis=1)[:, ::-1] + 3.0
    return z, rng.uniform(-1, 1, (rows, summits)), rng.uniform(-1, 1, (rows, summits))


def test_three_summits_carry_the_weight_by_the_lever_rule() -> None:
    # statically determinate: P_i = W·b_i (barycentric coordinates of the centre of mass), any heights
    x = np.array([[-0.8, 0.9, 0.1]])
    y = np.array([[-0.5, -0.2, 0.95]])
    z = np.array([[0.3, -0.4, 0.1]])
    weight = 0.7
    plane = _rest(z, x, y, weight)
    corners = np.stack([np.ones(3), x[0], y[0]])
    share = np.linalg.solve(corners, [1.0, 0.0, 0.0])
    delta = z[0] - (plane[0, 0] + plane[0, 1] * x[0] + plane[0, 2] * y[0])
    np.testing.assert_allclose(delta, (weight * share) ** (2 / 3), rtol=1e-9)
    # equal heights, centroid at the centre of mass: level, W/3 each
    x, y = np.array([[-0.5, 0.5, 0.0]]), np.array([[-0.3, -0.3, 0.6]])
    plane = _rest(np.zeros((1, 3)), x, y, weight)
    np.testing.assert_allclose(plane[0], [-((weight / 3) ** (2 / 3)), 0.0, 0.0], atol=1e-12)


def test_rigid_rest_is_the_linear_programs_optimum() -> None:
    z, x, y = _random_field(1, rows=15)
    plane, touching = _rigid_rest(z, x, y)
    for r in range(z.shape[0]):
        # lowest height at the centre of mass of a plane above every summit
        lp = linprog(
            [1, 0, 0],
            A_ub=-np.stack([np.ones_like(x[r]), x[r], y[r]], 1),
            b_ub=-z[r],
            bounds=[(None, None)] * 3,
        )
        assert plane[r, 0] == pytest.approx(lp.fun, abs=1e-10)
        # the three contacts touch and their triangle holds the centre of mass
        gap = plane[r, 0] + plane[r, 1] * x[r] + plane[r, 2] * y[r] - z[r]
        assert gap.min() > -1e-10
        np.testing.assert_allclose(gap[touching[r]], 0.0, atol=1e-10)
        tri = np.stack([x[r, touching[r]], y[r, touching[r]]], 1)
        assert Delaunay(tri).find_simplex([0.0, 0.0]) >= 0


def test_elastic_rest_balances_forces_and_matches_a_general_minimiser() -> None:
    z, x, y = _random_field(2, rows=12)
    weight = 0.4
    plane = _rest(z, x, y, weight)
    for r in range(z.shape[0]):
        delta = np.maximum(z[r] - (plane[r, 0] + plane[r, 1] * x[r] + plane[r, 2] * y[r]), 0.0)
        load = delta**1.5
        assert np.count_nonzero(delta) >= 3
        np.testing.assert_allclose([load.sum(), load @ x[r], load @ y[r]], [weight, 0, 0], atol=1e-10)

        def energy(p: np.ndarray, r: int = r) -> float:
            d = np.maximum(z[r] - (p[0] + p[1] * x[r] + p[2] * y[r]), 0.0)
            return float(weight * p[0] + 0.4 * np.sum(d**2.5))

        reference = minimize(
            energy,
            plane[r] + [0.05, 0.02, -0.02],
            method="Nelder-Mead",
            options={"xatol": 1e-10, "fatol": 1e-14, "maxiter": 20000},
        )
        np.testing.assert_allclose(reference.x, plane[r], atol=1e-6)


def test_the_highest_summits_drawn_give_the_same_rest_as_all_summits() -> None:
    # independent draw: every one of the N summits explicitly (few summits: a sparse surface)
    from dataclasses import replace

    surface = replace(DEFAULT_SURFACE, summit_density_per_m2=0.3e12)  # N ≈ 1900 under 80×80 µm
    part = Part.parse("80x80x50")
    sampled = rest_part(surface, part, placements=300, seed=5)
    rng = np.random.default_rng(11)
    n = rng.poisson(surface.summit_density_per_m2 * part.footprint_m2, 300)
    stiffness = 4 / 3 * surface.effective_modulus_pa * math.sqrt(surface.summit_radius_m)
    weight = part.weight_n / (stiffness * surface.sigma_m**1.5)
    zeta = np.sort(rng.normal(size=(300, n.max())), axis=1)[:, ::-1]
    zeta[np.arange(n.max()) >= n[:, None]] = -np.inf  # Poisson count of summits per placement
    x, y = rng.uniform(-1, 1, zeta.shape), rng.uniform(-1, 1, zeta.shape)
    p = _rest(zeta, x, y, weight)
    delta = np.maximum(zeta - (p[:, :1] + p[:, 1:2] * x + p[:, 2:3] * y), 0.0)
    areas = math.pi * surface.summit_radius_m * surface.sigma_m * delta.sum(axis=1)
    areas_all = areas
    standard_error = math.hypot(areas_all.std(), sampled.real_area_m2.std()) / math.sqrt(300)
    assert abs(areas_all.mean() - sampled.real_area_m2.mean()) < 3.5 * standard_error


def test_distributions_300_and_80_and_the_trend_to_gw() -> None:
    ratios, spreads, gw_area = [], [], []
    for label, placements in (
        ("80x80x50", 600),
        ("300x300x50", 600),
        ("1000x1000x50", 300),
        ("3000x3000x50", 80),
    ):
        r = rest_part(DEFAULT_SURFACE, Part.parse(label), placements=placements, seed=1)
        assert r.contacts.min() >= 3
        ratios.append(float(np.mean(r.real_area_m2)) / r.gw_real_area_m2)
        gw_area.append(r.gw_real_area_m2)
        spreads.append(float(np.std(r.real_area_m2) / np.mean(r.real_area_m2)))
    assert 2.65 < ratios[0] < 2.95  # 80×80: three contacts carry it; GW expects 0.23 asperities
    assert 1.33 < ratios[1] < 1.46  # 300×300: GW expects 3.2
    assert 1.02 < ratios[2] < 1.08
    assert abs(ratios[3] - 1.0) < 0.015  # 3×3 mm, ~320 contacts: GW's mean field holds
    assert ratios == sorted(ratios, reverse=True)
    assert spreads[1] > spreads[2] > spreads[3]
    # tilt matters: lowered level onto the same summits (one or two touch) the 80×80 part has less A_r
    level = sample_contact(DEFAULT_SURFACE, 6.4e-9, Part.parse("80x80x50").weight_n, placements=600)
    assert 1.9 < np.mean(level.real_area_m2) / gw_area[0] < 2.3


def test_grooved_support_deterministic_and_refuses_adhesion() -> None:
    from dataclasses import replace

    part = Part.parse("300x300x50")
    a = rest_part(DEFAULT_SURFACE, part, GROOVED, placements=200, seed=4)
    b = rest_part(DEFAULT_SURFACE, part, GROOVED, placements=200, seed=4)
    np.testing.assert_array_equal(a.real_area_m2, b.real_area_m2)
    assert np.all(a.largest_share <= 1.0) and np.all(a.tilt_rad > 0)
    assert 1.3 < np.mean(a.real_area_m2) / a.gw_real_area_m2 < 1.5
    with pytest.raises(Exception, match="Hertz-only"):
        rest_part(replace(DEFAULT_SURFACE, adhesion_work_j_m2=0.1), part)
