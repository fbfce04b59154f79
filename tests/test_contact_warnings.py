"""Plasticity index, Fuller–Tabor adhesion parameter and the contact model's warnings, by hand.

Documented default surface (DESIGN §2): E = 169 GPa, ν = 0.28 for both bodies
(E* = E/(2(1−ν²)) = 91.69 GPa), σ = 0.482 nm, R = 55.0 nm; silicon's hardness H = 12 GPa.
Thresholds: ψ > 0.6 borderline, ψ > 1 mostly plastic (Greenwood & Williamson); fewer than
10 contacting asperities breaks GW's statistics; adhesion above the weight dominates.
"""

from __future__ import annotations

import math
from dataclasses import replace

import mpmath
import pytest

from feeder.contact.breakaway import adhesion_parameter, contact
from feeder.parts import Part
from feeder.surface.parameters import DEFAULT_SURFACE, SurfaceParameters

PART = Part.parse("300x300x50")
E, NU, SIGMA, R, H = 169e9, 0.28, 0.482e-9, 55.0e-9, 12e9
WEIGHT_300 = 1.0285e-7  # N, paper table (silicon 300×300×50 µm)


def e_star() -> mpmath.mpf:
    return mpmath.mpf(E) / (2 * (1 - mpmath.mpf(NU) ** 2))


def plasticity(hardness: float) -> float:
    """ψ = (E*/H)·√(σ/R) (Greenwood & Williamson 1966), in mpmath."""
    return float(e_star() / hardness * mpmath.sqrt(mpmath.mpf(SIGMA) / R))


def with_psi(psi: float) -> SurfaceParameters:
    """The default surface with the hardness that gives this ψ."""
    return replace(DEFAULT_SURFACE, hardness_pa=plasticity(1.0) / psi)


def test_default_surface_is_the_documented_one() -> None:
    s = DEFAULT_SURFACE
    assert (s.youngs_modulus_pa, s.poisson_ratio, s.sigma_m, s.summit_radius_m) == (E, NU, SIGMA, R)
    assert s.hardness_pa == H
    assert s.effective_modulus_pa == pytest.approx(91.69e9, rel=1e-4)


def test_plasticity_index_of_the_default_surface() -> None:
    psi = DEFAULT_SURFACE.plasticity_index
    assert 0.715 <= psi <= 0.72  # the value the CLI warnings quote
    assert psi == pytest.approx(plasticity(H), rel=1e-12)
    # ψ ∝ √σ: four times the roughness doubles it
    assert replace(DEFAULT_SURFACE, sigma_m=4 * SIGMA).plasticity_index == pytest.approx(2 * psi, rel=1e-12)


def test_adhesion_parameter_is_fuller_tabor() -> None:
    """θ = E*·σ^{3/2}/(w·R^{1/2}): ≈ 83 for w = 0.05 J/m² (adhesion weak by Fuller–Tabor's θ ≲ 10)."""
    w = 0.05
    hand = float(e_star() * mpmath.mpf(SIGMA) ** 1.5 / (w * mpmath.sqrt(R)))
    assert hand == pytest.approx(82.74, rel=1e-3)
    surface = replace(DEFAULT_SURFACE, adhesion_work_j_m2=w)
    assert adhesion_parameter(surface) == pytest.approx(hand, rel=1e-12)
    # θ ∝ 1/w, so w = 0.5 J/m² is near Fuller–Tabor's threshold
    assert adhesion_parameter(replace(surface, adhesion_work_j_m2=0.5)) == pytest.approx(hand / 10, rel=1e-12)
    assert contact(PART, surface=surface).adhesion_parameter == pytest.approx(hand, rel=1e-12)


def plasticity_warnings(surface: SurfaceParameters) -> tuple[list[str], list[str]]:
    warnings = contact(PART, surface=surface).warnings
    plastic = [w for w in warnings if "plasticity index" in w and "most summits yield" in w]
    borderline = [w for w in warnings if "plasticity index" in w and "borderline" in w]
    return plastic, borderline


def test_default_surface_is_borderline_plastic() -> None:
    plastic, borderline = plasticity_warnings(DEFAULT_SURFACE)
    assert not plastic
    assert len(borderline) == 1 and "ψ = 0.72 > 0.6" in borderline[0]


@pytest.mark.parametrize(("psi", "expect"), [(0.55, "none"), (0.65, "borderline"), (0.95, "borderline"),
                                             (1.05, "plastic"), (3.0, "plastic")])  # fmt: skip
def test_plasticity_warning_thresholds(psi: float, expect: str) -> None:
    surface = with_psi(psi)
    assert surface.plasticity_index == pytest.approx(psi, rel=1e-9)
    plastic, borderline = plasticity_warnings(surface)
    assert (bool(plastic), bool(borderline)) == (expect == "plastic", expect == "borderline")


def few_contacts_warned(part: Part) -> bool:
    return any("asperities in contact" in w for w in contact(part).warnings)


def test_few_contacts_warning() -> None:
    """≈ 3.2 asperities under a 300×300 part (DESIGN §2: 'about 3'): N·F₀(h) with N = η·A_n and
    h = (d − μ)/σ at the paper's d = 34.637 nm; ~44× the area gives ~140: no warning."""
    n = 124.1e12 * (300e-6) ** 2
    h = (34.637e-9 - 32.227e-9) / SIGMA
    hand = n * 0.5 * math.erfc(h / math.sqrt(2))
    assert 2 < hand < 10
    result = contact(PART)
    assert result.contacts == pytest.approx(hand, rel=0.02)
    assert few_contacts_warned(PART)
    assert few_contacts_warned(Part.parse("80x80x50"))  # 0.23 contacts
    big = Part.parse("2000x2000x50")
    assert contact(big).contacts > 10 and not few_contacts_warned(big)


def test_adhesion_above_the_weight_is_reported() -> None:
    assert PART.weight_n == pytest.approx(WEIGHT_300, rel=1e-4, abs=0)

    def check(w: float) -> float:
        result = contact(PART, surface=replace(DEFAULT_SURFACE, adhesion_work_j_m2=w))
        warned = any("exceeds the part's weight" in x for x in result.warnings)
        assert warned == (result.adhesion_n > WEIGHT_300)
        return result.adhesion_n / WEIGHT_300

    assert 1 < check(0.01) < 10  # pulls harder than gravity, yet less than ten weights
    assert check(0.005) < 1
