"""Moments of inertia of planar parts and the turn of a part at O under a θ sawtooth.

Closed forms: a rectangle L×W about its centre m(L² + W²)/12; a disc of diameter L, m(L/2)²/2.
At O only the spin is left: the part turns like the 1-D part with the angular stroke Θ and the
kinetic angular deceleration α_k = τ_k·∫|ρ|dA / I (docs/plant.md), τ_k = F_k/A.  By hand:
square side L: ∫|ρ|dA = L³(√2 + ln(1 + √2))/6, I = mL²/6 → α_k = (√2 + ln(1 + √2))·a_k/L
(the documented 2.30·a_k/L); disc radius r: ∫|ρ|dA = 2πr³/3, I = mr²/2 → α_k = 4a_k/(3r).
"""

from __future__ import annotations

import math

import pytest

from feeder.parts import Part
from feeder.plant.planar import PlanarPart, simulate
from feeder.plant.plate_motion import sawtooth
from feeder.plant.stick_slip import Friction

A_S, RATIO = 105.25, 0.8
FREQ, T_F = 100.0, 3.5e-4
DENSITY = 2330.0  # silicon, kg/m³
SIDE, THICK = 300e-6, 50e-6


def test_rectangle_inertia_is_the_closed_form() -> None:
    part = Part.parse("300x200x50")
    mass = DENSITY * 300e-6 * 200e-6 * THICK
    planar = PlanarPart.from_part(part, Friction(A_S))
    assert planar.mass_kg == pytest.approx(mass, rel=1e-12, abs=0)
    closed = mass * ((300e-6) ** 2 + (200e-6) ** 2) / 12
    assert planar.inertia_kg_m2 == pytest.approx(closed, rel=1e-12, abs=0)


def test_disc_inertia_is_the_closed_form() -> None:
    part = Part.parse("300x300x50")
    radius = SIDE / 2
    mass = DENSITY * math.pi * radius**2 * THICK
    planar = PlanarPart.from_part(part, Friction(A_S), shape="disc")
    assert planar.mass_kg == pytest.approx(mass, rel=1e-12, abs=0)
    assert planar.inertia_kg_m2 == pytest.approx(mass * radius**2 / 2, rel=1e-12, abs=0)


def closed_turn(stroke_rad: float, alpha_k: float) -> float:
    """DESIGN §4 with angles: Θ(1 + t_f/t_r) − α_k t_f² if Θ(1/t_r + 1/t_f) > α_k t_f, else 0."""
    t_r = 1 / FREQ - T_F
    if stroke_rad * (1 / t_r + 1 / T_F) <= alpha_k * T_F:
        return 0.0
    return stroke_rad * (1 + T_F / t_r) - alpha_k * T_F**2


def turn_at_o(shape: str, stroke_rad: float) -> tuple[float, float, float]:
    part = PlanarPart.from_part(Part.parse("300x300x50"), Friction(A_S, RATIO), (0.0, 0.0, 0.0), shape)
    run = simulate([part], sawtooth((0.0, 0.0, stroke_rad), FREQ, T_F, "linear", 2))
    dx, dy, dpsi = (float(v) for v in run.changes[0][-1])
    return dx, dy, dpsi


def test_square_at_o_turns_by_the_rotational_closed_form() -> None:
    alpha_k = (math.sqrt(2) + math.log(1 + math.sqrt(2))) * RATIO * A_S / SIDE
    expected = closed_turn(0.1, alpha_k)
    assert expected > 0.01
    dx, dy, dpsi = turn_at_o("rectangle", 0.1)
    assert dpsi == pytest.approx(expected, rel=1e-6)
    assert abs(dx) < 1e-15 and abs(dy) < 1e-15


def test_disc_at_o_turns_by_the_rotational_closed_form() -> None:
    alpha_k = 4 * RATIO * A_S / (3 * SIDE / 2)
    expected = closed_turn(0.1, alpha_k)
    assert expected > 0.005
    dx, dy, dpsi = turn_at_o("disc", 0.1)
    assert dpsi == pytest.approx(expected, rel=1e-6)
    assert abs(dx) < 1e-15 and abs(dy) < 1e-15
