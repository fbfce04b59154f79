"""The step estimator: closed-form check against batch weighted least squares, convergence."""

from __future__ import annotations

import numpy as np
import pytest

from feeder.daemon.step_estimator import StepEstimate, StepEstimator


def test_without_forgetting_equals_batch_bayesian_least_squares() -> None:
    """λ = 1: RLS is the posterior mean of (s, c) under the prior and R(n)-weighted bursts."""
    rng = np.random.default_rng(3)
    seed = StepEstimate(3.3e-6, (0.5e-6) ** 2, 0, 0.2e-6, (1.0e-6) ** 2, 0.1e-12)
    noise, scatter = 0.1e-6, 0.2e-6
    est = StepEstimator(seed, sensor_noise_m=noise, step_scatter_m=scatter, forgetting=1.0)
    counts = rng.integers(1, 40, size=12)
    moves = counts * 2.9e-6 + 0.8e-6 + rng.normal(0, 0.3e-6, size=12)
    for n, y in zip(counts, moves, strict=True):
        est.update(int(n), float(y))
    h = np.column_stack([counts, np.ones_like(counts)]).astype(float)
    r = 2 * noise**2 + counts * scatter**2
    p0 = np.array([[seed.variance_m2, seed.covariance_m2], [seed.covariance_m2, seed.offset_variance_m2]])
    information = np.linalg.inv(p0) + h.T @ (h / r[:, None])
    mean = np.linalg.solve(information, np.linalg.inv(p0) @ [seed.step_m, seed.offset_m] + h.T @ (moves / r))
    cov = np.linalg.inv(information)
    e = est.estimate
    assert [e.step_m, e.offset_m] == pytest.approx(mean, rel=1e-9)
    assert [e.variance_m2, e.covariance_m2, e.offset_variance_m2] == pytest.approx(
        [cov[0, 0], cov[0, 1], cov[1, 1]], rel=1e-6
    )
    assert e.steps == counts.sum()
    assert e.displacement_m(7) == pytest.approx(7 * e.step_m + e.offset_m, rel=1e-15)


def simulate(bursts: list[int], seed_error: float, offset_fraction: float, trials: int = 300) -> np.ndarray:
    """Relative error of the learned step after ``bursts``: true step 3 µm, 2 % step-to-step
    scatter and 50 nm camera noise (firmware_sim's defaults)."""
    true_step, noise, scatter = 3.0e-6, 0.05e-6, 0.02
    rng = np.random.default_rng(11)
    errors = []
    for _ in range(trials):
        est = StepEstimator(
            StepEstimate.seed(true_step * (1 + seed_error), 0.2 * true_step),
            sensor_noise_m=noise,
            step_scatter_m=scatter * true_step,
        )
        for n in bursts:
            steps = true_step * (1 + scatter * rng.standard_normal(n))
            moved = (
                steps.sum()
                + offset_fraction * true_step
                + noise * (rng.standard_normal() - rng.standard_normal())
            )
            est.update(n, moved)
        errors.append(est.step_m / true_step - 1)
    return np.array(errors)


@pytest.mark.parametrize("bursts", [[5, 15], [2, 3, 15], [5, 5, 10], [10, 4, 6], [20]])
@pytest.mark.parametrize("seed_error", [+0.15, -0.15])
@pytest.mark.parametrize("offset_fraction", [0.0, 0.27])
def test_seeded_15_percent_off_converges_within_5_percent_in_20_steps(
    bursts: list[int], seed_error: float, offset_fraction: float
) -> None:
    errors = simulate(bursts, seed_error, offset_fraction)
    assert np.mean(np.abs(errors) < 0.05) >= 0.99


def test_bursts_of_one_length_pin_their_own_displacement() -> None:
    """Twenty 1-step bursts cannot tell s from c, but they learn s + c, what one step does."""
    true_step, offset = 1.0e-6, 0.16e-6
    est = StepEstimator(StepEstimate.seed(1.15e-6, 0.2e-6), sensor_noise_m=0.05e-6, step_scatter_m=0.02e-6)
    rng = np.random.default_rng(2)
    for _ in range(20):
        est.update(1, true_step + offset + rng.normal(0, 0.07e-6))
    assert est.estimate.displacement_m(1) == pytest.approx(true_step + offset, rel=0.05)


def test_forgetting_follows_a_change_of_the_true_step() -> None:
    """After the friction changes (step 3 → 2 µm) λ < 1 follows; λ = 1 lags behind."""
    rng = np.random.default_rng(5)
    seed = StepEstimate.seed(3e-6, 0.3e-6)
    forgetful = StepEstimator(seed, sensor_noise_m=0.1e-6, step_scatter_m=0.1e-6, forgetting=0.9)
    stubborn = StepEstimator(seed, sensor_noise_m=0.1e-6, step_scatter_m=0.1e-6, forgetting=1.0)
    for i, true in enumerate([3e-6] * 50 + [2e-6] * 40):
        n = 5 if i % 2 else 15
        y = n * true + rng.normal(0, 0.2e-6)
        forgetful.update(n, y)
        stubborn.update(n, y)
    assert abs(forgetful.step_m - 2e-6) < 0.05e-6
    assert abs(stubborn.step_m - 2e-6) > 0.1e-6


def test_rejects_bad_seed_and_burst() -> None:
    with pytest.raises(ValueError):
        StepEstimator(StepEstimate(0.0, 1e-12), sensor_noise_m=1e-7, step_scatter_m=1e-7)
    est = StepEstimator(StepEstimate.seed(1e-6, 1e-7), sensor_noise_m=1e-7, step_scatter_m=1e-7)
    with pytest.raises(ValueError):
        est.update(0, 0.0)
