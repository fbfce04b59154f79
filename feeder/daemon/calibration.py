"""The daemon's ``calibrate`` job: its bursts and how many steps fit the travel (no I/O).

A calibration runs both waveforms (coarse, fine) forward then back, so the
part ends about where it started; the daemon learns each step and burst
offset from it (:mod:`feeder.daemon.step_estimator`).
"""

from __future__ import annotations

import math

from feeder.daemon.jobs import Burst, LoopSettings, StepMode
from feeder.daemon.line_navigator import COARSE, FINE
from feeder.daemon.step_estimator import BACKWARD, FORWARD, StepEstimate

CALIBRATION_STEPS = 20
"""Coarse steps per direction when a request gives none."""
ROOM_AHEAD = 1.25
"""The forward excursion's margin (pessimistic step, then 25 %) before the upper travel limit."""
ROOM_BEHIND = 0.25
"""The return's asymmetry (a quarter of the excursion) kept behind the part."""


def calibration_bursts(coarse_steps: int, fine_steps: int) -> tuple[Burst, ...]:
    """Per waveform and direction: one step (takes up a reversal, not learned from), then a
    short and a long burst (¼ and ¾ of the steps: two lengths separate the step from the
    burst offset).  The part ends about where it started."""
    bursts = []
    for mode, total in ((COARSE, coarse_steps), (FINE, fine_steps)):
        short = max(1, total // 4)
        for direction in (FORWARD, BACKWARD):
            bursts += [
                Burst(mode, direction, 1),
                Burst(mode, direction, short),
                Burst(mode, direction, total - short),
            ]
    return tuple(bursts)


def fine_steps_for(coarse_steps: int, modes: dict[str, StepMode]) -> int:
    """Fine steps per direction covering a quarter of the coarse bursts' way (at least 2)."""
    ratio = modes[COARSE].predicted_step_m / modes[FINE].predicted_step_m
    return max(2, round(coarse_steps * ratio / 4))


def calibration_room(
    position_m: float, settings: LoopSettings, estimate: StepEstimate, predicted_high_m: float
) -> int | str:
    """The most coarse steps per direction a calibration may take from ``position_m`` (m), or the
    reason there is no room.

    The bursts go forward first and come back: the excursion at a pessimistic step (the learned
    step + 2σ, at least ``predicted_high_m``, the top of the predicted band) must fit before the
    upper limit with :data:`ROOM_AHEAD`, the return's asymmetry (:data:`ROOM_BEHIND`) behind.
    """
    step_high = max(estimate.step_m + 2 * math.sqrt(estimate.variance_m2), predicted_high_m)
    ahead, behind = settings.max_position_m - position_m, position_m - settings.min_position_m
    allowed = math.floor(min(ahead / ROOM_AHEAD, behind / ROOM_BEHIND) / step_high) - 1
    if allowed < 2:
        return (
            f"no room to calibrate: the part at {position_m:.6g} m is {ahead:.3g} m from the "
            f"upper and {behind:.3g} m from the lower travel limit; move it inwards"
        )
    return allowed
