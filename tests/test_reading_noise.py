"""The sensor's noise measured from readings of parts at rest (feeder.reading_noise), and the
daemon's policy feeding it only while nothing moves the parts."""

from __future__ import annotations

import numpy as np
import pytest
from test_policy import Rig, play_to_the_end, to_first_burst

from feeder.daemon.status_report import sensor_noise
from feeder.reading_noise import MIN_CHANGES, RENEW_EVERY, RestingNoise


def _readings(rng: np.random.Generator, count: int, sigma_m: float) -> np.ndarray:
    """Two parts at rest (count, 4): x and y of each with noise ``sigma_m``."""
    return np.array([1e-3, 0.5e-3, -1e-3, 0.2e-3]) + rng.normal(0.0, sigma_m, (count, 4))


def test_the_noise_of_parts_at_rest_is_measured_through_a_nudge_and_a_drift() -> None:
    """σ 0.3 µm over 300 readings of two parts: within 10 %, though one part was nudged 20 µm
    halfway and both drift 0.5 µm a reading (a creeping stack); nothing is stated before
    :data:`MIN_CHANGES` changes."""
    readings = _readings(np.random.default_rng(3), 300, 0.3e-6)
    readings[150:, 0] += 20e-6
    readings[:, 1::2] += 0.5e-6 * np.arange(300)[:, None]
    noise = RestingNoise()
    for k, reading in enumerate(readings):
        noise.add(reading)
        if 4 * (k - 1) < MIN_CHANGES:  # 4 coordinates: 4 changes of changes per reading from the 3rd
            assert noise.sigma_m is None
    assert noise.sigma_m == pytest.approx(0.3e-6, rel=0.1)


def test_no_change_spans_a_restart() -> None:
    """Readings split by a restart give the same σ whatever the parts did in between (a move of
    1 mm here), and a run too short to state σ keeps the last one stated."""
    rng = np.random.default_rng(5)
    first, second = _readings(rng, 100, 0.2e-6), _readings(rng, 100, 0.2e-6)
    still, moved = RestingNoise(), RestingNoise()
    for noise, offset in ((still, 0.0), (moved, 1e-3)):
        for reading in first:
            noise.add(reading)
        noise.restart()
        for reading in second:
            noise.add(reading + offset)
    assert still.sigma_m is not None and moved.sigma_m == pytest.approx(still.sigma_m, rel=1e-9)
    assert moved.sigma_m == pytest.approx(0.2e-6, rel=0.15)
    stated = moved.sigma_m
    for _ in range(RENEW_EVERY - 1):
        moved.restart()
        moved.add(second[0] + 1.0)  # single readings: no change at all
    assert moved.sigma_m == stated


def test_the_policy_measures_the_noise_only_while_nothing_moves_the_parts() -> None:
    """Idle readings count; a move's do not (its first reading after the burst would be a
    change of ~100 µm), nor do those while the output is lent (a camera calibration's ramps)."""
    rig = Rig()
    rng = np.random.default_rng(7)
    for _ in range(MIN_CHANGES + 20):
        rig.position_m = rng.normal(0.0, 0.4e-6)
        rig.tick()
    idle = rig.policy.resting_noise.sigma_m
    assert idle == pytest.approx(0.4e-6, rel=0.3)
    _, step = to_first_burst(rig, 30e-6)
    rig.complete(step, counter=0)
    rig.position_m = step.steps * 3.0e-6
    rig.complete(rig.run_until_command("confirm_end"))
    play_to_the_end(rig)
    assert rig.policy.state == "idle" and rig.policy.resting_noise.sigma_m == idle
    rig.policy.output_lent()
    for k in range(100):  # a ramp that is not noise: 1 µm, then 2 µm a reading
        rig.position_m += (1 + k % 2) * 1e-6
        rig.tick()
    rig.policy.output_taken()
    assert rig.policy.resting_noise.sigma_m == idle


def test_status_warns_when_the_sensor_is_noisier_than_configured() -> None:
    assert sensor_noise(None, 0.1e-6)["sensor_noise_warning"] is None  # not measured yet
    assert sensor_noise(0.19e-6, 0.1e-6)["sensor_noise_warning"] is None
    warned = sensor_noise(0.31e-6, 0.1e-6)
    assert warned["sensor_noise_seen_m"] == 0.31e-6 and warned["sensor_noise_m"] == 0.1e-6
    assert warned["sensor_noise_warning"].startswith(
        "the sensor's readings of parts at rest scatter 0.31 µm (1σ), "
        "over 2 × [control] sensor_noise_m = 0.1 µm"
    )
    assert sensor_noise(1e-9, 0.0)["sensor_noise_warning"] is not None  # configured 0: any noise
