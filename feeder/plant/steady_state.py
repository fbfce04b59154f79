"""Where a run of per-period steps has reached its steady state.

A part that re-sticks within every period starts each period in the same state: the step
repeats from the second period on (the first starts from rest).  A part that slides
through whole periods (a flyback longer than the rise, a drive near the threshold) carries
its velocity into the next period, and the step drifts for many periods before it settles,
possibly with the other sign: 38.0, 29.6, 21.2, …, −17.6, −18.1, −18.1 µm for a 500×500×50
part on the ideal plate at 2 kHz with a 0.35 ms flyback.  The steady step is the one the
run settles on; :func:`steady_start` finds where that begins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from feeder.plant.ideal_plate import sawtooth_motion
from feeder.plant.stick_slip import simulate_batch

STEADY_RTOL = 1e-3
"""Steps within this fraction of the run's largest |step| of the last one are settled."""
MAX_STEADY_PERIODS = 512
"""The most periods :func:`ideal_steady_steps` simulates to find a steady state."""


def steady_start(steps: np.ndarray, rtol: float = STEADY_RTOL) -> tuple[np.ndarray, np.ndarray]:
    """(first steady period index ≥ 1, settled) per row of ``steps`` (sets, periods), or for one run.

    The steady periods are the last ones within ``rtol`` × max|step| of the last step; the
    first period is never counted (it starts from rest).  ``settled``: at least the last two
    periods agree, i.e. the run shows its steady state (False for fewer than 3 periods).
    """
    steps = np.atleast_2d(np.asarray(steps, dtype=float))
    n = steps.shape[1]
    tol = rtol * np.max(np.abs(steps), axis=1, initial=0.0)
    off = np.abs(steps - steps[:, -1:]) > tol[:, None]
    off[:, 0] = True  # the first period starts from rest
    # index after the last period that is off the final step
    last_off = n - 1 - np.argmax(off[:, ::-1], axis=1)
    start = np.minimum(last_off + 1, n - 1)
    return start, (n - start >= 2) & (n >= 3)


@dataclass(frozen=True)
class SteadySteps:
    """Per parameter set: the steady step (m, mean over the settled periods) and its std, the
    periods before it (the transient), whether the run settled, and the slip fraction of the
    whole run."""

    step_m: np.ndarray
    std_m: np.ndarray
    transient_periods: np.ndarray
    settled: np.ndarray
    slip_fraction: np.ndarray


def ideal_steady_steps(
    stroke_m: np.ndarray | float,
    frequency_hz: np.ndarray | float,
    flyback_s: np.ndarray | float,
    shape: str,
    static_accel_m_s2: np.ndarray | float,
    kinetic_ratio: np.ndarray | float,
    periods: int = 3,
) -> SteadySteps:
    """The ideal plate's steady step per set (arrays broadcast over the sets): ``periods``
    periods (at least 3) from rest, doubled for the sets not yet settled up to
    :data:`MAX_STEADY_PERIODS`."""
    stroke, freq, t_f, a_s, ratio = np.broadcast_arrays(
        *(np.atleast_1d(np.asarray(v, dtype=float)) for v in (stroke_m, frequency_hz, flyback_s,
                                                              static_accel_m_s2, kinetic_ratio))
    )  # fmt: skip
    sets = stroke.size
    out = SteadySteps(np.zeros(sets), np.zeros(sets), np.zeros(sets, dtype=int), np.zeros(sets, dtype=bool),
                      np.zeros(sets))  # fmt: skip
    todo = np.arange(stroke.size)
    n = max(3, periods)
    while todo.size:
        motion = sawtooth_motion(stroke[todo], freq[todo], t_f[todo], shape, n)
        rel, slip = simulate_batch(
            motion.accel_m_s2, motion.duration_s, motion.jump_m_s, a_s[todo], ratio[todo]
        )
        per = motion.intervals_per_period
        steps = np.diff(np.concatenate([np.zeros((todo.size, 1)), rel[:, per - 1 :: per]], axis=1), axis=1)
        start, ok = steady_start(steps)
        done = ok | (n >= MAX_STEADY_PERIODS)
        for row in np.flatnonzero(done):
            k, tail = todo[row], steps[row, start[row] :]
            out.step_m[k], out.std_m[k] = tail.mean(), tail.std(ddof=1) if tail.size > 1 else 0.0
            out.transient_periods[k], out.settled[k] = start[row], ok[row]
            out.slip_fraction[k] = slip[row] * freq[k] / n
        todo = todo[~done]
        n = min(2 * n, MAX_STEADY_PERIODS)
    return out
