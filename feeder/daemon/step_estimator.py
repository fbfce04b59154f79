"""Online estimate of the real step size, one per direction (and per waveform).

A burst of ``n`` steps moves the part by ``Δx = n·s + c + v``: ``s`` is the
steady step (paper §V.B), ``c`` the extra slip after the burst's last flyback
(in steady stepping the next ramp absorbs it; at the end of a burst nothing
does), ``v`` noise of variance ``R(n) = 2σ_x² + n·σ_s²`` (two sensor readings
of noise σ_x, independent step-to-step scatter σ_s).  θ = (s, c) is estimated
by recursive least squares with exponential forgetting, written as its
equivalent Kalman filter with H = (n, 1): before each update the covariance is
inflated, ``P ← P/λ`` (λ < 1 forgets old bursts, so a slow drift of the
friction is followed), then

    S = H·P·Hᵀ + R(n),   K = P·Hᵀ/S,   θ ← θ + K·(Δx − H·θ),   P ← P − K·S·Kᵀ.

It is seeded by the planner's prediction: ``s₀`` = predicted step with
``var s₀`` = (half-width of the predicted band)², and ``c₀ = 0`` with a broad
``var c₀`` = (s₀/2)².  Bursts of different lengths separate ``s`` from ``c``;
bursts of one length only pin ``n·s + c`` (which is what they need).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

FORWARD = "forward"
BACKWARD = "backward"
DIRECTIONS = (FORWARD, BACKWARD)


@dataclass(frozen=True)
class StepEstimate:
    """Step ``s`` (m), burst offset ``c`` (m), their covariance (m²), and steps observed."""

    step_m: float
    variance_m2: float
    steps: int = 0
    offset_m: float = 0.0
    offset_variance_m2: float = 0.0
    covariance_m2: float = 0.0

    @classmethod
    def seed(cls, step_m: float, step_std_m: float) -> StepEstimate:
        """The prior: a predicted step ± std, offset 0 ± step/2."""
        return cls(step_m, step_std_m**2, 0, 0.0, (0.5 * step_m) ** 2, 0.0)

    @property
    def finite(self) -> bool:
        """Whether every figure is a number (a step learned from a broken reading may not be)."""
        return all(math.isfinite(v) for v in (self.step_m, self.variance_m2, self.offset_m,
                                              self.offset_variance_m2, self.covariance_m2))  # fmt: skip

    @property
    def std_m(self) -> float:
        return math.sqrt(self.variance_m2)

    @property
    def offset_std_m(self) -> float:
        return math.sqrt(self.offset_variance_m2)

    def displacement_m(self, steps: int) -> float:
        """Expected displacement of a burst of ``steps`` steps: n·s + c."""
        return steps * self.step_m + self.offset_m


class StepEstimator:
    """RLS with forgetting for the step (and burst offset) of one direction of one waveform.

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
        if not (seed.step_m > 0 and seed.variance_m2 > 0 and seed.offset_variance_m2 >= 0):
            raise ValueError("seed step and variance must be positive")
        if not 0 < forgetting <= 1:
            raise ValueError("forgetting must be in (0, 1]")
        self.estimate = seed
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
        theta = np.array([est.step_m, est.offset_m])
        p = (
            np.array([[est.variance_m2, est.covariance_m2], [est.covariance_m2, est.offset_variance_m2]])
            / self.forgetting
        )
        h = np.array([float(steps), 1.0])
        s = float(h @ p @ h) + self.measurement_variance_m2(steps)
        gain = p @ h / s
        theta = theta + gain * (displacement_m - float(h @ theta))
        p = p - s * np.outer(gain, gain)
        p = 0.5 * (p + p.T)
        self.estimate = StepEstimate(
            float(theta[0]),
            float(p[0, 0]),
            est.steps + steps,
            float(theta[1]),
            float(p[1, 1]),
            float(p[0, 1]),
        )
        return self.estimate

    def usable_step_m(self) -> float:
        """The step estimate, floored at 1 nm so a near-zero estimate never divides by zero."""
        return max(self.estimate.step_m, 1e-9)
