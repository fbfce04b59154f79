"""F_k/F_s band: ± 0.1 around the ratio (docs/plant.md), never above 1 (F_k ≤ F_s) nor at 0."""

from __future__ import annotations

import pytest

from feeder.parts import Part
from feeder.planner import predict_step
from feeder.plant.plant import run_waveform
from feeder.plant.stick_slip import Friction, kinetic_ratio_band
from feeder.waveform import Waveform


def test_documented_band() -> None:
    assert kinetic_ratio_band(0.8) == pytest.approx((0.7, 0.9), abs=1e-15)


@pytest.mark.parametrize("ratio", [0.95, 1.0])
def test_upper_end_is_at_most_one(ratio: float) -> None:
    lo, hi = kinetic_ratio_band(ratio)
    assert lo == pytest.approx(ratio - 0.1, abs=1e-15)
    assert hi == 1.0  # kinetic friction cannot exceed static friction


def test_step_band_near_equal_frictions_uses_f_k_equal_f_s() -> None:
    """F_k/F_s = 0.95: the weakest end of the band is the high-τ a_s with F_k = F_s."""
    part = Part.parse("300x300x50")
    wave = Waveform(frequency_hz=100.0, amplitude_vpp=100.0)
    s = predict_step(wave, part, kinetic_ratio=0.95)
    a_hi = 105.25 * (22.18 + 3.15) / 22.18  # a_break ∝ τ, τ = 22.18 ± 3.15 GPa
    weakest = float(run_waveform(Friction(a_hi, 1.0), wave, 2).steps_m[-1])
    assert s.band_m[0] == pytest.approx(weakest, rel=1e-3, abs=0)
    assert 0 < s.band_m[0] < s.step_m < s.band_m[1]
