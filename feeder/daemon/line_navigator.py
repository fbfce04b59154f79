"""The closed loop's decisions along one axis: where to step next and what a burst taught.

The policy (:mod:`feeder.daemon.policy`) measures, steps and records; a
*navigator* decides.  :class:`LineNavigator` is the one-axis feeder: the part
is a point on the x axis of the plate (the first part's x when the sensor sees
poses).  Far from the target the *coarse* waveform aims one coarse step short
(never past the target); the last stretch uses the *fine* waveform, whose step
is at most twice the tolerance, so the final error is at most half a fine step
plus scatter: no overshoot, no hunting.  A part within tolerance but more than
half a fine step away gets one more fine step (once per move).  The estimators
learn from every burst but the first after a direction reversal (or the first
of all): that one loses part of a step to the plate's state left by the other
direction.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from feeder.daemon.jobs import VISIBLE_BANDS, Burst, Job, LoopSettings, Reading, StepMode
from feeder.daemon.step_estimator import BACKWARD, DIRECTIONS, FORWARD, StepEstimate, StepEstimator

COARSE = "coarse"
FINE = "fine"


def mean_reading(samples: list[Reading]) -> Reading:
    """The average of ``samples`` part by part; angles averaged as offsets from the first."""
    first = samples[0]
    out = []
    for i, (_, _, psi0) in enumerate(first):
        xs = [s[i][0] for s in samples]
        ys = [s[i][1] for s in samples]
        dpsi = [math.remainder(s[i][2] - psi0, 2 * math.pi) for s in samples]
        out.append((float(np.mean(xs)), float(np.mean(ys)), psi0 + float(np.mean(dpsi))))
    return tuple(out)


class LineNavigator:
    """Decisions along the x axis of part 1 (see the module doc).

    modes: ``"coarse"``/``"fine"`` → :class:`~feeder.daemon.jobs.StepMode`;
    estimates: learned steps to restore, keyed ``"mode/direction"``.
    """

    axes: tuple[str, ...] = ("x",)

    def __init__(
        self,
        modes: dict[str, StepMode],
        settings: LoopSettings,
        estimates: dict[str, StepEstimate] | None = None,
    ) -> None:
        if set(modes) != {COARSE, FINE}:
            raise ValueError("modes must be exactly 'coarse' and 'fine'")
        self.modes = modes
        self.settings = settings
        self.estimators: dict[str, StepEstimator] = {}
        restored = estimates or {}
        for name, mode in modes.items():
            for direction in DIRECTIONS:
                key = f"{name}/{direction}"
                self.estimators[key] = StepEstimator(
                    restored.get(key, mode.seed),
                    sensor_noise_m=settings.sensor_noise_m,
                    step_scatter_m=settings.step_scatter_fraction * mode.predicted_step_m,
                    forgetting=settings.forgetting,
                )

    # -- the job's target --------------------------------------------------------------

    def prepare(self, job: Job, reading: Reading | None) -> str | None:
        """Resolve a relative move against ``reading``; the reason ``job`` is refused, or None."""
        s = self.settings
        if job.pose_target is not None:
            return "this configuration moves one axis: give target_m (x), not a pose"
        if job.part != 1:
            return f"this configuration moves one part along x: there is no part {job.part}"
        if job.by_m is not None:
            if reading is None:
                return "position uncertain: no sensor reading yet for a relative move"
            job.target_m = reading[0][0] + job.by_m
        if job.target_m is not None and not (s.min_position_m <= job.target_m <= s.max_position_m):
            return (
                f"target {job.target_m:.6g} m is outside the travel limits "
                f"[{s.min_position_m:.6g}, {s.max_position_m:.6g}] m"
            )
        return None

    def outside(self, reading: Reading) -> str | None:
        """Why ``reading`` is outside the travel, or None."""
        s = self.settings
        x = reading[0][0]
        if s.min_position_m <= x <= s.max_position_m:
            return None
        return f"part at {x:.6g} m is outside the travel limits"

    def settled(self, recent: list[Reading]) -> bool:
        """The readings agree within the tolerance (or six sensor sigmas)."""
        s = self.settings
        xs = [r[0][0] for r in recent]
        return max(xs) - min(xs) <= s.settle_band_m

    # -- bursts -----------------------------------------------------------------------

    def learn(self, burst: Burst, learnable: bool, before: Reading, after: Reading) -> bool:
        """Learn from a burst that moved the part from ``before`` to ``after``; True if it stalled:
        it moved under ``stall_fraction`` of what was expected, and either nothing beyond the
        settle band or after the step was learned (a seed several times off a real device's
        step is learned from, not taken for a stall)."""
        sign = 1.0 if burst.direction == FORWARD else -1.0
        moved = sign * (after[0][0] - before[0][0])
        est = self.estimators[f"{burst.mode}/{burst.direction}"]
        expected = est.estimate.displacement_m(burst.steps)
        if not learnable:  # e.g. after a reversal: may lose up to a step
            expected -= est.estimate.step_m
        if moved < self.settings.stall_fraction * expected and (
            est.estimate.steps > 0 or moved <= self.settings.settle_band_m
        ):
            return True
        if learnable:
            est.update(burst.steps, moved)
        return False

    def expects_motion(self, burst: Burst, reading: Reading) -> bool:
        """The burst should move the part by over :data:`VISIBLE_BANDS` settle bands."""
        expected = self.estimators[f"{burst.mode}/{burst.direction}"].estimate.displacement_m(burst.steps)
        return expected > VISIBLE_BANDS * self.settings.settle_band_m

    def next_burst(self, job: Job, reading: Reading) -> Burst | tuple[str, str]:
        """The next burst towards ``job.target_m``, or (status, reason) when the job is over."""
        s = self.settings
        x = reading[0][0]
        assert job.target_m is not None
        error = job.target_m - x
        direction = FORWARD if error > 0 else BACKWARD
        distance = abs(error)
        coarse = self.estimators[f"{COARSE}/{direction}"]
        fine = self.estimators[f"{FINE}/{direction}"]
        single = fine.estimate.displacement_m(1)  # what one fine step does
        if distance <= s.tolerance_m:
            # within tolerance; one fine step more when it brings the part closer (once per
            # move, so it can never start hunting)
            if job.refined or distance <= 0.5 * single:
                return ("done", "within tolerance")
            job.refined = True
            return Burst(FINE, direction, 1)
        # aim one step short with a pessimistic (mean + 2σ) step and offset: never past the target
        c = coarse.estimate
        step_high = c.step_m + 2 * c.std_m
        offset_high = c.offset_m + 2 * c.offset_std_m
        coarse_steps = math.floor((distance - offset_high) / step_high) - 1
        if coarse_steps >= 1 and coarse.usable_step_m() > fine.usable_step_m():
            return Burst(COARSE, direction, min(coarse_steps, s.max_burst_steps))
        steps = round((distance - fine.estimate.offset_m) / fine.usable_step_m())
        if steps < 1:
            if abs(distance - single) >= distance:
                return (
                    "unreachable",
                    f"one fine step ({single:.3g} m) cannot reduce the "
                    f"error {error:.3g} m below the tolerance {s.tolerance_m:.3g} m",
                )
            steps = 1
        return Burst(FINE, direction, min(steps, s.max_burst_steps))

    def reached(self, job: Job, reading: Reading) -> None:
        """Nothing to remember: the next move starts from wherever the part is."""

    def release(self, part: int | None = None) -> list[int]:
        """One axis holds no part."""
        return []

    def holds(self) -> list[dict[str, Any]]:
        return []

    # -- what it learned ---------------------------------------------------------------

    def estimates(self) -> dict[str, StepEstimate]:
        return {k: e.estimate for k, e in self.estimators.items()}

    def estimates_json(self) -> dict[str, Any]:
        """Learned step and burst offset per ``mode/direction`` (m), for replies."""
        return {
            k: {
                "step_m": e.step_m,
                "std_m": e.std_m,
                "offset_m": e.offset_m,
                "offset_std_m": e.offset_std_m,
                "steps": e.steps,
            }
            for k, e in self.estimates().items()
        }
