"""The step estimator: closed-form check against batch weighted least squares, convergence."""

from __future__ import annotations

import numpy as np
import pytest

from feeder.daemon.step_estimator import StepEstimate, StepEstimator


def test_without_forgetting_equals_batch_bayesian_least_squares() -> None:
    """λ = 1: RLS is the posterior mean of s under the prior (s0, P0) and R(n)-weighted bursts."""
    rng = np.random.default_rng(3)
    s0, p0, noise, scatter = 3.3e-6, (0.5e-6) ** 2, 0.1e-6, 0.2e-6
    est = StepEstimator(StepEstimate(s0, p0), sensor_noise_m=noise, step_scatter_m=scatter,
                        forgetting=1.0)
    counts = rng.integers(1, 40, size=12)
    moves = counts * 2.9e-6 + rng.normal(0, 0.3e-6, size=12)
    for n, y in zip(counts, moves, strict=True):
        est.update(int(n), float(y))
    r = 2 * noise**2 + counts * scatter**2
    information = 1 / p0 + np.sum(counts**2 / r)
    mean = (s0 / p0 + np.sum(counts * moves / r)) / information
    assert est.step_m == pytest.approx(mean, rel=1e-12)
    assert est.estimate.variance_m2 == pytest.approx(1 / information, rel=1e-9)
    assert est.estimate.steps == counts.sum()


@pytest.mark.parametrize("bursts", [[1] * 20, [20], [5, 5, 10], [2, 3, 15]])
@pytest.mark.parametrize("seed_error", [+0.15, -0.15])
def test_seeded_15_percent_off_converges_within_5_percent_in_20_steps(
    bursts: list[int], seed_error: float
) -> None:
    true_step, noise, scatter = 3.0e-6, 0.1e-6, 0.05
    rng = np.random.default_rng(11)
    trials, good = 300, 0
    for _ in range(trials):
        seed = StepEstimate(true_step * (1 + seed_error), (0.2 * true_step) ** 2)
        est = StepEstimator(seed, sensor_noise_m=noise, step_scatter_m=scatter * true_step)
        for n in bursts:
            steps = true_step * (1 + scatter * rng.standard_normal(n))
            moved = steps.sum() + noise * (rng.standard_normal() - rng.standard_normal())
            est.update(n, moved)
        good += abs(est.step_m / true_step - 1) < 0.05
    assert good / trials >= 0.99


def test_forgetting_follows_a_change_of_the_true_step() -> None:
    """After the friction changes (step 3 → 2 µm) λ < 1 follows; λ = 1 lags behind."""
    rng = np.random.default_rng(5)
    seed = StepEstimate(3e-6, (0.3e-6) ** 2)
    forgetful = StepEstimator(seed, sensor_noise_m=0.1e-6, step_scatter_m=0.1e-6, forgetting=0.9)
    stubborn = StepEstimator(seed, sensor_noise_m=0.1e-6, step_scatter_m=0.1e-6, forgetting=1.0)
    for true in [3e-6] * 50 + [2e-6] * 40:
        y = 10 * true + rng.normal(0, 0.2e-6)
        forgetful.update(10, y)
        stubborn.update(10, y)
    assert abs(forgetful.step_m - 2e-6) < 0.05e-6
    assert abs(stubborn.step_m - 2e-6) > 0.1e-6


def test_rejects_bad_seed_and_burst() -> None:
    with pytest.raises(ValueError):
        StepEstimator(StepEstimate(0.0, 1e-12), sensor_noise_m=1e-7, step_scatter_m=1e-7)
    est = StepEstimator(StepEstimate(1e-6, 1e-14), sensor_noise_m=1e-7, step_scatter_m=1e-7)
    with pytest.raises(ValueError):
        est.update(0, 0.0)
