"""The paper's Tables I and III with the embedded default surface (DESIGN §2)."""

from __future__ import annotations

import pytest

from feeder.contact.breakaway import contact
from feeder.paper import GROOVED_AREA_RATIO, PAPER_ROWS, SEPARATION_FLAT_M
from feeder.parts import FLAT, GROOVED, Part

PARTS = list(PAPER_ROWS)


@pytest.mark.parametrize("label", PARTS)
def test_table_i_weights_to_four_significant_digits(label: str) -> None:
    weight = Part.parse(label).weight_n
    assert float(f"{weight:.4e}") == pytest.approx(PAPER_ROWS[label].weight_n, rel=1e-4)


@pytest.mark.parametrize("label", PARTS)
def test_flat_separation_and_real_area(label: str) -> None:
    result = contact(Part.parse(label), FLAT)
    assert result.separation_m == pytest.approx(SEPARATION_FLAT_M, abs=0.005e-9)
    assert result.real_area_m2 == pytest.approx(PAPER_ROWS[label].real_area_flat_m2, rel=2e-3)


def test_real_area_proportional_to_weight_and_same_breakaway_accel() -> None:
    results = [contact(Part.parse(label), FLAT) for label in PARTS]
    ratios = [r.real_area_m2 / r.weight_n for r in results]
    assert max(ratios) == pytest.approx(min(ratios), rel=1e-9)
    accels = [r.breakaway_accel_m_s2 for r in results]
    assert max(accels) == pytest.approx(min(accels), rel=1e-9)
    assert accels[0] == pytest.approx(105.0, rel=0.01)  # ≈ 10.7 g


def test_tau_band_carries_to_force_and_accel() -> None:
    r = contact(Part.parse("300x300x50"), FLAT, tau_pa=20e9, tau_band_pa=2e9)
    assert r.breakaway_force_n == pytest.approx(20e9 * r.real_area_m2)
    assert r.breakaway_force_band_n == pytest.approx((18e9 * r.real_area_m2, 22e9 * r.real_area_m2))
    lo, hi = r.breakaway_accel_band_m_s2
    assert (lo, hi) == pytest.approx(
        (r.breakaway_force_band_n[0] / r.mass_kg, r.breakaway_force_band_n[1] / r.mass_kg)
    )


def test_contact_counts_and_honest_warnings() -> None:
    big = contact(Part.parse("300x300x50"), FLAT)
    small = contact(Part.parse("80x80x50"), FLAT)
    assert big.contacts == pytest.approx(3.2, abs=0.2)
    assert small.contacts == pytest.approx(0.23, abs=0.02)
    assert any("asperities in contact" in w for w in small.warnings)
    assert any("ideal shear strength" in w for w in big.warnings)
    low_tau = contact(Part.parse("300x300x50"), FLAT, tau_pa=5e9, tau_band_pa=1e9)
    assert not any("ideal shear strength" in w for w in low_tau.warnings)


def test_grooved_support_cannot_reach_the_papers_ratio_and_says_so() -> None:
    part = Part.parse("300x300x50")
    flat, grooved = contact(part, FLAT), contact(part, GROOVED)
    ratio = grooved.real_area_m2 / flat.real_area_m2
    assert 0.97 < ratio < 1.0  # halving N at the same load changes A_r by ~1 %
    assert abs(ratio - GROOVED_AREA_RATIO) > 0.2
    assert any("0.76" in w for w in grooved.warnings)
