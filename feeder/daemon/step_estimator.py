"""Online estimate of the real step size, one per direction (and per waveform).

The measurement model of a burst of ``n`` steps is ``Δx = n·s + v`` with the
unknown step ``s`` and noise ``v`` of variance ``R(n) = 2σ_x² + n·σ_s²`` (two
sensor readings of noise σ_x, independent step-to-step scatter σ_s).  ``s`` is
estimated by scalar recursive least squares with exponential forgetting,
written as its equivalent Kalman filter: before each update the variance is
inflated, ``P ← P/λ`` (λ < 1 forgets old bursts, so a slow drift of the
friction is followed), then

    K = P·n / (n²·P + R(n)),   s ← s + K·(Δx − n·s),   P ← (1 − K·n)·P.

It is seeded by the planner's prediction (paper §V.B): ``s₀`` = predicted step,
``P₀`` = (half-width of the predicted band)², so a good prediction is trusted
and a bad one is corrected within the first burst.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

FORWARD = "forward"
BACKWARD = "backward"
DIRECTIONS = (FORWARD, BACKWARD)


@dataclass
class StepEstimate:
    """Step size (m, positive) and its variance (m²) after ``steps`` observed steps."""

    step_m: float
    variance_m2: float
    steps: int = 0

    @property
    def std_m(self) -> float:
        return math.sqrt(self.variance_m2)


class StepEstimator:
    """RLS with forgetting for the step size of one direction of one waveform.

    sensor_noise_m: σ_x of one position reading (m).
    step_scatter_m: σ_s, step-to-step scatter (m).
    forgetting: λ in (0, 1]; 1 = no forgetting.
    """

    def __init__(
        self,
        seed: StepEstimate,
        *,
        sensor_noise_m: float,
        step_scatter_m: float,
        forgetting: float = 0.98,
    ) -> None:
        if not (seed.step_m > 0 and seed.variance_m2 > 0):
            raise ValueError("seed step and variance must be positive")
        if not 0 < forgetting <= 1:
            raise ValueError("forgetting must be in (0, 1]")
        self.estimate = StepEstimate(seed.step_m, seed.variance_m2, seed.steps)
        self.sensor_noise_m = sensor_noise_m
        self.step_scatter_m = step_scatter_m
        self.forgetting = forgetting

    @property
    def step_m(self) -> float:
        return self.estimate.step_m

    def measurement_variance_m2(self, steps: int) -> float:
        """R(n) = 2σ_x² + n·σ_s² for a burst of ``steps`` steps."""
        return 2 * self.sensor_noise_m**2 + steps * self.step_scatter_m**2

    def update(self, steps: int, displacement_m: float) -> StepEstimate:
        """Fold in a burst of ``steps`` (> 0) that moved the part by ``displacement_m``.

        ``displacement_m`` is measured along the burst's own direction (positive
        when the part moved the way it was driven).
        """
        if steps <= 0:
            raise ValueError("steps must be positive")
        est = self.estimate
        p = est.variance_m2 / self.forgetting
        gain = p * steps / (steps * steps * p + self.measurement_variance_m2(steps))
        step = est.step_m + gain * (displacement_m - steps * est.step_m)
        p = (1.0 - gain * steps) * p
        self.estimate = StepEstimate(step, p, est.steps + steps)
        return self.estimate

    def usable_step_m(self) -> float:
        """The estimate, floored at 1 nm so a near-zero estimate never divides by zero."""
        return max(self.estimate.step_m, 1e-9)
