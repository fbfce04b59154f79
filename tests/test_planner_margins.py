"""Planner margins against the ends of the breakaway band, fewest steps, the ideal-plate frequency choice.

Everything is recomputed by hand from the documented defaults (docs/plant.md: stack 0.07 µm/V,
1 µF, R_out 8 Ω, f_n 30 kHz; amplifier 0.55 A, 200 Vpp, 1 Hz–2 kHz; a_break = 105.25 m/s² for
every part size on the flat support; τ = 22.18 ± 3.15 GPa, so a_break ∝ τ) and DESIGN §4
(step = S(1 + t_f/t_r) − a_k·t_f² with a_k = (F_k/F_s)·a_s), not from the planner's helpers.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from feeder.errors import InputError
from feeder.parts import Part
from feeder.planner import _AMPLITUDE_GRID, _FREQUENCY_GRID, plan
from feeder.plant.plant import run_waveform
from feeder.plant.stick_slip import Friction
from feeder.waveform import Waveform

PART = Part.parse("300x300x50")
A_BREAK = 105.25  # m/s², docs/plant.md (τ·A_r/m at τ = 22.18 GPa)
TAU, TAU_BAND = 22.18e9, 3.15e9
MARGIN = 1.2  # k of docs/plant.md
GAIN, CAPACITANCE, CURRENT = 0.07e-6, 1e-6, 0.55
RESPONSE_S = 1 / (2 * 30e3) + 8.0 * CAPACITANCE  # 1/(2 f_n) + R_out·C: no flyback is shorter
MAX_VPP, MIN_HZ, MAX_HZ = 200.0, 1.0, 2000.0


def accel_at(tau_pa: float) -> float:
    """a_break ∝ τ (A_r and m do not depend on τ)."""
    return A_BREAK * tau_pa / TAU


def sawtooth(volts: np.ndarray | float, freq: np.ndarray | float) -> tuple[np.ndarray, ...]:
    """(flyback accel, ramp accel, stroke, t_r, t_f) of a current-limited sawtooth, by hand.

    The output falls at I/C while the command already rises again at V·f: t_f = V/(I/C + V·f);
    the stroke is the swing 1 − t_f·f of V times the gain; t_f never below the stack's response."""
    v, f = np.asarray(volts, dtype=float), np.asarray(freq, dtype=float)
    t_current = v / (CURRENT / CAPACITANCE + v * f)
    stroke = GAIN * v * (1 - t_current * f)
    t_f = np.maximum(t_current, RESPONSE_S)
    t_r = 1 / f - t_f
    return stroke * (1 / t_r + 1 / t_f) / t_f, 2 * stroke / t_r**2, stroke, t_r, t_f


def plant_step(waveform: Waveform, static_accel: float) -> float:
    return float(run_waveform(Friction(static_accel), waveform, 3).steps_m[-1])


def test_reported_margins_are_taken_at_the_ends_of_the_band() -> None:
    """flyback_margin = flyback accel / a_break(upper); ramp_margin = a_break(lower) / ramp accel."""
    p = plan(PART, distance_m=500e-6)
    fly, ramp, *_ = (float(x) for x in sawtooth(p.amplitude_vpp, p.frequency_hz))
    a_lo, a_hi = accel_at(TAU - TAU_BAND), accel_at(TAU + TAU_BAND)
    assert p.breakaway_accel_band_m_s2 == pytest.approx((a_lo, a_hi), rel=1e-4)
    assert p.margins["flyback_margin"] == pytest.approx(fly / a_hi, rel=1e-4)
    assert p.margins["ramp_margin"] == pytest.approx(a_lo / ramp, rel=1e-4)
    assert p.margins["ramp_margin"] >= MARGIN and p.margins["flyback_margin"] >= MARGIN


def test_flyback_margin_is_met_at_the_upper_end_of_a_wide_band() -> None:
    """τ = 22.18 ± 10 GPa at 100 Hz: the step's peak lies where flyback accel ≈ 1.45 a_s but
    < 1.2·a_break(upper); the plan must stay below it (the part must break loose at high τ)."""
    band = 10e9
    p = plan(PART, distance_m=1e-3, frequency_hz=100.0, tau_band_pa=band)
    fly, ramp, _, t_r, t_f = (float(x) for x in sawtooth(p.amplitude_vpp, p.frequency_hz))
    a_lo, a_hi = accel_at(TAU - band), accel_at(TAU + band)
    assert fly >= MARGIN * a_hi * (1 - 1e-6)
    assert p.margins["flyback_margin"] >= MARGIN
    assert ramp <= a_lo / MARGIN and t_r >= 4 * t_f


def test_refuses_when_only_the_nominal_tau_breaks_loose() -> None:
    """τ = 260 ± 40 GPa: the best flyback acceleration within the amplifier's limits exceeds
    1.2·a_s but not 1.2·a_break(upper): the plan must be refused, naming the upper end."""
    tau, band = 260e9, 40e9
    volts = np.linspace(0.5, MAX_VPP, 800)
    freqs = np.geomspace(MIN_HZ, MAX_HZ, 200)
    fly, _, _, t_r, t_f = sawtooth(volts[None, :], freqs[:, None])
    best = float(np.max(np.where(t_r >= 4 * t_f, fly, 0.0)))
    assert MARGIN * accel_at(tau) < best < MARGIN * accel_at(tau + band)
    with pytest.raises(InputError, match="upper end of the breakaway band"):
        plan(PART, distance_m=100e-6, tau_pa=tau, tau_band_pa=band)


def test_a_distance_below_the_smallest_step_takes_one_step_and_says_so() -> None:
    """10 nm: even the smallest amplitude meeting the margins steps more (stroke ≈ 0.15 µm at
    2 V).  One step is the fewest (and already overshoots); the overshoot must be reported."""
    distance = 10e-9
    p = plan(PART, distance_m=distance)
    step = plant_step(p.waveform(), A_BREAK)
    assert step > distance  # one step of the planned waveform already covers the distance
    assert p.steps == 1
    assert p.predicted_step_m == pytest.approx(step, rel=1e-3, abs=0)
    assert any("smallest amplitude" in w and "more than" in w for w in p.warnings)


def test_no_overshoot_warning_when_the_distance_is_met() -> None:
    p = plan(PART, distance_m=500e-6)
    assert p.steps * p.predicted_step_m == pytest.approx(500e-6, rel=1e-6, abs=0)
    assert not any("smallest amplitude" in w for w in p.warnings)


def test_one_micrometre_at_100_hz_is_one_step() -> None:
    """At 100 Hz a 50 Vpp sawtooth meets both margins and steps > 1 µm on the plant model, so
    1 µm needs a single step; the planner must not plan more."""
    fly, ramp, _, t_r, t_f = (float(x) for x in sawtooth(50.0, 100.0))
    assert fly >= MARGIN * accel_at(TAU + TAU_BAND) and ramp <= accel_at(TAU - TAU_BAND) / MARGIN
    assert t_r >= 4 * t_f
    assert plant_step(Waveform(frequency_hz=100.0, amplitude_vpp=50.0), A_BREAK) > 1e-6
    p = plan(PART, distance_m=1e-6, frequency_hz=100.0)
    assert p.steps == 1
    assert p.predicted_step_m == pytest.approx(1e-6, rel=1e-6, abs=0)


def test_frequency_choice_uses_the_kinetic_deceleration() -> None:
    """F_k/F_s = 0.3 over 20 µm: the candidate frequencies (the amplifier's range on a log grid)
    are ranked by the ideal-plate step of DESIGN §4 with a_k = 0.3·a_s, done here by hand;
    the planner picks the shortest move."""
    ratio, distance = 0.3, 20e-6
    freqs = np.geomspace(MIN_HZ, MAX_HZ, _FREQUENCY_GRID)
    volts = MAX_VPP * np.arange(1, _AMPLITUDE_GRID + 1) / _AMPLITUDE_GRID
    fly, ramp, stroke, t_r, t_f = sawtooth(volts[None, :], freqs[:, None])
    a_s, a_lo, a_hi = A_BREAK, accel_at(TAU - TAU_BAND), accel_at(TAU + TAU_BAND)
    ok = (fly >= MARGIN * a_hi) & (t_r >= 4 * t_f) & (ramp <= a_lo / MARGIN)

    def fastest(decel: float) -> float:
        moves = stroke * (1 / t_r + 1 / t_f) > decel * t_f
        with np.errstate(divide="ignore", invalid="ignore"):
            ideal = np.where(ok & moves, stroke * (1 + t_f / t_r) - decel * t_f**2, 0.0)
            best = ideal.max(axis=1)
            duration = np.where(best > 0, np.ceil(distance / best) / freqs, np.inf)
        return float(freqs[int(np.argmin(duration))])

    chosen = fastest(ratio * a_s)
    assert chosen != fastest(a_s)  # the kinetic level matters here: F_s instead ranks another first
    p = plan(PART, distance_m=distance, kinetic_ratio=ratio)
    assert p.frequency_hz == pytest.approx(chosen, rel=1e-9)
    assert math.isfinite(p.duration_s)
