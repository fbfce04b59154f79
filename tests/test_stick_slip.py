"""Exact stick-slip: closed form, no-motion, an independent fine-step reference, batch = streaming."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from feeder.errors import InputError
from feeder.plant.ideal_plate import linear_flyback_step, sawtooth_motion
from feeder.plant.stick_slip import Friction, StickSlip, simulate_batch


def closed_form(stroke: float, t_r: float, t_f: float, a_k: float) -> float:
    """DESIGN §4, written out independently of the library."""
    if stroke * (1 / t_r + 1 / t_f) > a_k * t_f:
        return stroke * (1 + t_f / t_r) - a_k * t_f**2
    return 0.0


def streamed_steps(
    stroke: float,
    freq: float,
    t_f: float,
    a_s: float,
    ratio: float,
    shape: str,
    periods: int = 4,
    direction: float = 1.0,
) -> np.ndarray:
    motion = sawtooth_motion(stroke, freq, t_f, shape, periods, direction)
    solver = StickSlip(Friction(a_s, ratio))
    rel = solver.advance(motion.accel_m_s2[0], motion.duration_s[0], motion.jump_m_s[0])
    per = motion.intervals_per_period
    return np.diff(np.concatenate(([0.0], rel[per - 1 :: per])))


@settings(max_examples=60, deadline=None)
@given(
    stroke=st.floats(1e-6, 30e-6),
    freq=st.floats(10.0, 1000.0),
    fly_fraction=st.floats(1e-3, 0.45),
    a_s=st.floats(5.0, 2000.0),
    ratio=st.floats(0.3, 1.0),
)
def test_linear_flyback_matches_closed_form(
    stroke: float, freq: float, fly_fraction: float, a_s: float, ratio: float
) -> None:
    t_f = fly_fraction / freq
    t_r = 1 / freq - t_f
    expected = closed_form(stroke, t_r, t_f, ratio * a_s)
    steps = streamed_steps(stroke, freq, t_f, a_s, ratio, "linear")
    assert np.all(np.abs(steps - expected) <= 1e-9 * max(abs(expected), stroke * 1e-3))
    assert float(linear_flyback_step(stroke, t_r, t_f, ratio * a_s)) == pytest.approx(
        expected, rel=1e-12, abs=1e-25
    )


def test_closed_form_both_regimes_in_one_batch() -> None:
    """A sweep of flyback times across the motion threshold, all parameter sets at once."""
    stroke, freq, a_s, ratio = 5e-6, 100.0, 105.0, 0.8
    t_f = np.geomspace(2e-5, 4e-3, 200)
    motion = sawtooth_motion(stroke, freq, t_f, "linear", periods=3)
    rel, _ = simulate_batch(motion.accel_m_s2, motion.duration_s, motion.jump_m_s, a_s, ratio)
    steps = rel[:, -1] - rel[:, -3]
    expected = np.array([closed_form(stroke, 1 / freq - t, t, ratio * a_s) for t in t_f])
    moving = expected > 0
    assert moving.any() and (~moving).any()
    np.testing.assert_allclose(steps[moving], expected[moving], rtol=1e-9)
    assert np.all(np.abs(steps[~moving]) < 1e-9 * stroke)


def test_paper_numbers_half_ms_flyback_does_not_move() -> None:
    """DESIGN §4: with a 0.5 ms fall nothing moves (14 µm stroke, a_k = 0.8·105 m/s²)."""
    steps = streamed_steps(14e-6, 100.0, 0.5e-3, 105.0, 0.8, "linear")
    assert np.all(np.abs(steps) < 1e-15)
    moving = streamed_steps(14e-6, 100.0, 0.3e-3, 105.0, 0.8, "linear")
    assert moving[-1] > 3e-6


def test_backward_mirrors_forward() -> None:
    fwd = streamed_steps(8e-6, 200.0, 1e-4, 105.0, 0.8, "half-cosine")
    bwd = streamed_steps(8e-6, 200.0, 1e-4, 105.0, 0.8, "half-cosine", direction=-1.0)
    np.testing.assert_allclose(bwd, -fwd, rtol=1e-12)
    assert fwd[-1] > 0


def test_no_motion_when_plate_acceleration_stays_below_breakaway() -> None:
    """A smooth plate motion whose |a| never exceeds a_s carries the part exactly."""
    rng = np.random.default_rng(1)
    a_s = 105.0
    t = np.linspace(0, 0.05, 20001)
    accel = 0.0
    for f in rng.uniform(50, 2000, 6):  # sum of sines scaled to peak 0.999·a_s
        accel = accel + np.sin(2 * np.pi * f * t + rng.uniform(0, 6.3))
    accel = 0.999 * a_s * accel / np.max(np.abs(accel))
    solver = StickSlip(Friction(a_s))
    rel = solver.advance(accel[:-1], np.diff(t))
    assert np.all(rel == 0.0)
    assert solver.slip_time_s == 0.0
    over = solver.advance(np.array([1.001 * a_s, 0.0]), 1e-4)
    assert over[-1] != 0.0 and solver.slip_time_s > 0


def _euler_step(
    rel: float,
    v_part: float,
    stuck: bool,
    v0: float,
    v1: float,
    a_mid: float,
    dt: float,
    a_s: float,
    a_k: float,
) -> tuple[float, float, bool]:
    """One fixed step of the part on a plate going from velocity v0 to v1 (mid acceleration a_mid)."""
    if stuck and abs(a_mid) <= a_s:
        return rel, v1, True
    w0 = v_part - v0
    pull = -math.copysign(a_k, w0) if w0 != 0 else math.copysign(a_k, a_mid)
    v_new = v_part + pull * dt
    w1 = v_new - v1
    if w0 != 0 and (w1 == 0 or (w0 > 0) != (w1 > 0)):
        frac = w0 / (w0 - w1)  # zero crossing inside the step
        rel += 0.5 * w0 * frac * dt
        if abs(a_mid) <= a_s:
            return rel, v1, True
        return rel + 0.5 * w1 * (1 - frac) * dt, v_new, False
    return rel + 0.5 * (w0 + w1) * dt, v_new, False


def fine_step_half_cosine(
    stroke: float, freq: float, t_f: float, a_s: float, ratio: float, substeps: int = 100_000
) -> float:
    """Independent reference: the exact cosine plate, fixed steps of dt = t_f/substeps.

    Starts at the top of the rise with the part stuck: the flyback's start is a
    velocity corner (rise velocity → 0), its end another (0 → rise velocity).
    Integrates the flyback, then the rise until the part has re-stuck (nothing
    changes after that within the period).  Returns x_part − x_plate, the step.
    """
    v_rise = stroke / (1 / freq - t_f)
    a_k = ratio * a_s
    dt = t_f / substeps
    amp_v = stroke * math.pi / (2 * t_f)
    amp_a = stroke * math.pi**2 / (2 * t_f**2)
    rel, v_part, stuck = 0.0, v_rise, False
    for k in range(substeps):
        v0 = -amp_v * math.sin(math.pi * k / substeps)
        v1 = -amp_v * math.sin(math.pi * (k + 1) / substeps)
        a_mid = -amp_a * math.cos(math.pi * (k + 0.5) / substeps)
        rel, v_part, stuck = _euler_step(rel, v_part, stuck, v0, v1, a_mid, dt, a_s, a_k)
    stuck = False  # the corner at the end of the flyback
    if v_part == v_rise:
        return rel
    while not stuck:
        rel, v_part, stuck = _euler_step(rel, v_part, stuck, v_rise, v_rise, 0.0, dt, a_s, a_k)
    return rel


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    ("stroke", "freq", "t_f", "a_s"),
    [(14e-6, 100.0, 3.5e-4, 105.0), (5e-6, 100.0, 1e-4, 105.0), (10e-6, 500.0, 2e-4, 300.0)],
)
def test_half_cosine_agrees_with_fine_step_reference(
    stroke: float, freq: float, t_f: float, a_s: float
) -> None:
    reference = fine_step_half_cosine(stroke, freq, t_f, a_s, 0.8)
    ours = streamed_steps(stroke, freq, t_f, a_s, 0.8, "half-cosine", periods=2)
    assert reference > 0.1e-6
    assert ours[-1] == pytest.approx(reference, rel=1e-3)
    assert ours[0] == pytest.approx(ours[-1], rel=1e-12)


def test_half_cosine_converges_with_pieces() -> None:
    """Mean-acceleration pieces: error falls roughly as pieces⁻²."""
    args = (14e-6, 100.0, 3.5e-4)
    values = []
    for pieces in (50, 100, 200, 3200):
        m = sawtooth_motion(*args, "half-cosine", periods=1, cosine_pieces=pieces)
        rel, _ = simulate_batch(m.accel_m_s2, m.duration_s, m.jump_m_s, 105.0, 0.8)
        values.append(rel[0, -1])
    errors = [abs(v - values[-1]) for v in values[:-1]]
    assert errors[0] > errors[1] > errors[2]
    assert errors[0] / errors[2] > 8  # ≈ 16 for second order


def random_motion(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    accel = rng.normal(0, 150, n)
    dt = rng.uniform(1e-6, 5e-5, n)
    jump = np.where(rng.random(n) < 0.05, rng.normal(0, 0.01, n), 0.0)
    return accel, dt, jump


def test_streaming_equals_batch_and_chunking_does_not_matter() -> None:
    rng = np.random.default_rng(7)
    accel, dt, jump = random_motion(rng, 3000)
    whole = StickSlip(Friction(105.0, 0.7)).advance(accel, dt, jump)
    batch, slip = simulate_batch(accel, dt, jump, 105.0, 0.7)
    np.testing.assert_allclose(whole, batch[0], rtol=1e-9, atol=1e-18)
    chunked = StickSlip(Friction(105.0, 0.7))
    cuts = np.sort(rng.choice(np.arange(1, 3000), 40, replace=False))
    parts = [
        chunked.advance(a, d, j)
        for a, d, j in zip(np.split(accel, cuts), np.split(dt, cuts), np.split(jump, cuts), strict=True)
    ]
    np.testing.assert_allclose(np.concatenate(parts), whole, rtol=1e-12, atol=1e-20)
    assert chunked.slip_time_s == pytest.approx(float(slip[0]), rel=1e-9)


def test_batch_sets_are_independent() -> None:
    rng = np.random.default_rng(3)
    sets = [random_motion(rng, 500) for _ in range(5)]
    a_s = np.array([50.0, 80.0, 105.0, 150.0, 400.0])
    batch, _ = simulate_batch(
        np.stack([s[0] for s in sets]),
        np.stack([s[1] for s in sets]),
        np.stack([s[2] for s in sets]),
        a_s,
        0.8,
    )
    for k, (a, d, j) in enumerate(sets):
        alone = StickSlip(Friction(float(a_s[k]), 0.8)).advance(a, d, j)
        np.testing.assert_allclose(batch[k], alone, rtol=1e-9, atol=1e-18)


def test_scatter_is_seeded_and_changes_steps() -> None:
    motion = sawtooth_motion(14e-6, 100.0, 3.5e-4, "linear", periods=30)
    args = (motion.accel_m_s2[0], motion.duration_s[0], motion.jump_m_s[0])
    one = StickSlip(Friction(105.0), scatter=0.1, seed=5).advance(*args)
    two = StickSlip(Friction(105.0), scatter=0.1, seed=5).advance(*args)
    np.testing.assert_array_equal(one, two)
    steps = np.diff(one[1::2])
    assert np.std(steps) > 1e-8


def test_friction_validation() -> None:
    with pytest.raises(InputError, match="kinetic_ratio"):
        Friction(100.0, 1.5)
    with pytest.raises(InputError, match="static_accel"):
        Friction(-1.0)


def test_closed_form_only_where_the_part_resticks_within_the_rise() -> None:
    """t_f > t_r: the part never re-sticks; the closed form says NaN, the solver still works."""
    assert math.isnan(float(linear_flyback_step(14e-6, 1.5e-4, 3.5e-4, 84.0)))
    steps = streamed_steps(14e-6, 2000.0, 3.5e-4, 105.0, 0.8, "linear", periods=30)
    assert np.all(np.isfinite(steps)) and abs(steps[-1] - steps[-2]) < 1e-12
