"""A plate that follows the sawtooth exactly (no amplifier or stack dynamics).

The plate's motion is cut into intervals of constant acceleration with velocity
jumps at the sawtooth's corners, the input of :mod:`feeder.plant.stick_slip`:

- rise: one interval, constant velocity S/t_r;
- ``linear`` flyback: one interval, constant velocity −S/t_f (jumps at both corners);
- ``half-cosine`` flyback, x = S/2·(1 + cos πτ/t_f): ``cosine_pieces`` intervals
  whose accelerations are the exact mean accelerations (velocity exact at the
  nodes), so the stick-slip on it converges as pieces⁻².

Each period is the flyback followed by the rise.  The motion starts in the
periodic steady state: plate at the top, x = S, moving at the rise velocity,
part stuck to it; so each period ends with the part stuck again and the
relative displacement at period ends is the step.  Arrays broadcast over
parameter sets (batch).

Closed form for the linear flyback (DESIGN §4): the corner at the start of the
flyback is a velocity jump S(1/t_r + 1/t_f), the part slips with kinetic
deceleration a_k; if it is still slipping when the flyback ends it is dragged
back up to the rise velocity in another t_f, and
``step = S(1 + t_f/t_r) − a_k·t_f²`` when ``S(1/t_r + 1/t_f) > a_k·t_f``; else
it re-sticks during the flyback and the two corners cancel: step 0.  Both
need t_f ≤ t_r; at shorter rises the part never re-sticks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

COSINE_PIECES = 400


@dataclass(frozen=True)
class PlateMotion:
    """Plate motion as intervals, arrays (sets, intervals).

    duration_s, accel_m_s2: each interval; jump_m_s: velocity jump at its start;
    position_m: plate position at its end (the motion starts at x = ±S);
    intervals_per_period.
    """

    duration_s: np.ndarray
    accel_m_s2: np.ndarray
    jump_m_s: np.ndarray
    position_m: np.ndarray
    intervals_per_period: int


def sawtooth_motion(
    stroke_m: np.ndarray | float,
    frequency_hz: np.ndarray | float,
    flyback_s: np.ndarray | float,
    flyback_shape: str = "linear",
    periods: int = 1,
    direction_sign: float = 1.0,
    cosine_pieces: int = COSINE_PIECES,
) -> PlateMotion:
    """Ideal-plate intervals for ``periods`` periods (flyback, then rise) of a sawtooth.

    stroke_m S, frequency_hz f and flyback_s t_f broadcast over parameter sets;
    t_r = 1/f − t_f.  direction_sign −1 mirrors the motion (backward).
    """
    stroke, freq, t_f = (np.atleast_1d(np.asarray(v, dtype=float)) for v in np.broadcast_arrays(
        stroke_m, frequency_hz, flyback_s))  # fmt: skip
    t_r = 1.0 / freq - t_f
    v_rise = stroke / t_r
    sets = stroke.size
    if flyback_shape == "linear":
        v_fly = -stroke / t_f
        dur = np.stack([t_f, t_r], axis=1)
        acc = np.zeros((sets, 2))
        jmp = np.stack([v_fly - v_rise, v_rise - v_fly], axis=1)
        pos = np.stack([np.zeros(sets), stroke], axis=1)
    elif flyback_shape == "half-cosine":
        nodes = np.linspace(0.0, 1.0, cosine_pieces + 1)[None, :]
        v_nodes = -(stroke * np.pi / (2 * t_f))[:, None] * np.sin(np.pi * nodes)
        h = (t_f / cosine_pieces)[:, None]
        dur = np.concatenate([np.broadcast_to(h, (sets, cosine_pieces)), t_r[:, None]], axis=1)
        acc = np.concatenate([np.diff(v_nodes, axis=1) / h, np.zeros((sets, 1))], axis=1)
        jmp = np.zeros_like(dur)
        jmp[:, 0] = -v_rise
        jmp[:, -1] = v_rise
        pos = np.concatenate(
            [0.5 * stroke[:, None] * (1 + np.cos(np.pi * nodes[:, 1:])), stroke[:, None]], axis=1
        )
    else:
        raise ValueError(f"ideal plate has no flyback shape {flyback_shape!r}")
    return PlateMotion(
        duration_s=np.tile(dur, (1, periods)),
        accel_m_s2=direction_sign * np.tile(acc, (1, periods)),
        jump_m_s=direction_sign * np.tile(jmp, (1, periods)),
        position_m=direction_sign * np.tile(pos, (1, periods)),
        intervals_per_period=dur.shape[1],
    )


def linear_flyback_step(
    stroke_m: np.ndarray | float,
    rise_s: np.ndarray | float,
    flyback_s: np.ndarray | float,
    kinetic_accel_m_s2: np.ndarray | float,
) -> np.ndarray:
    """Closed-form step per period (m) for a linear flyback on an ideal plate (DESIGN §4).

    Valid while t_f ≤ t_r (the part re-sticks within the rise); NaN otherwise,
    where the part never re-sticks and only the solver can tell.
    """
    s, t_r, t_f, a_k = (np.asarray(v, dtype=float) for v in (stroke_m, rise_s, flyback_s,
                                                              kinetic_accel_m_s2))  # fmt: skip
    moves = s * (1 / t_r + 1 / t_f) > a_k * t_f
    step = np.where(moves, s * (1 + t_f / t_r) - a_k * t_f**2, 0.0)
    return np.where(t_f <= t_r, step, np.nan)
