"""The compiled planar solver's arrays (:mod:`.planar_kernels`): their layouts, and the plate's motion and
frames on them.

A segment is ``SEG_SIZE`` floats (duration, velocity, acceleration, cosine
amplitude per axis, κ; :class:`.plate_motion.Segment`); the plate is (x_O, y_O,
θ, v_x, v_y, Ω, elapsed time); a part's parameters are ``PARAM_SIZE`` floats
(:func:`part_params`); its state ``STATE_SIZE`` floats (stuck, plate-frame
pose, lab state while slipping, slip time, stop threshold, last step size,
fade step, Dormand-Prince steps tried so far, the derivative carried to the
next segment and where); a drive row ``DRIVE_SIZE`` floats per channel.
"""

from __future__ import annotations

import math

import numpy as np

from feeder.plant.kernels import DRIVE_STATES, _jit, _jit_inline

SEG_SIZE = 11
DURATION, V, A, C, KAPPA = 0, 1, 4, 7, 10
PLATE_SIZE = 7
ELAPSED = 6
DRIVE_VOLTS, DRIVE_SCALE = DRIVE_STATES + 6, DRIVE_STATES + 7
DRIVE_SIZE = DRIVE_STATES + 8
"""A channel's drive row (:func:`run_plant`): coefficients and filter states, voltage, scale."""
PARAM_SIZE = 16
DISC, HALF_A, HALF_B, MASS, INERTIA, TAU_S, TAU_K, A_S, RATIO, AREA, POLAR, JXX, JYY, RTOL = range(14)
HOLD_F, HOLD_M = 14, 15
"""HOLD_F = m/(τ_s·A) (s²/m), HOLD_M = I/(τ_s·P) (s²): a wrench's diamond measure per unit of acceleration."""
STATE_SIZE = 23
STUCK, POSE, LAB, SLIP, STOP, STEP, RADIUS, FADE_STEP, STEPS = 0, 1, 4, 10, 11, 12, 13, 14, 15
DERIV, DERIV_AT = 16, 22
"""DERIV: d(lab state)/dt where the last slip reached its segment's end, still slipping (6 floats);
DERIV_AT: the plate's elapsed time there (0: none).  The next segment's slip starts from it (the
rhs is continuous where the plate's velocity is: first same as last)."""


def part_params(disc: bool, length_m: float, width_m: float, mass_kg: float, inertia_kg_m2: float,
                static_accel_m_s2: float, kinetic_ratio: float, area_m2: float, polar_m3: float,
                second_moments_m4: tuple[float, float], rtol: float) -> np.ndarray:  # fmt: skip
    """A part's parameter row (τ_s = m·a_s/A, τ_k = r·τ_s as :class:`.planar_reference.PartState`; rtol
    of its slips)."""
    tau_s = mass_kg * static_accel_m_s2 / area_m2
    return np.array([1.0 if disc else 0.0, 0.5 * length_m, 0.5 * width_m, mass_kg, inertia_kg_m2, tau_s,
                     kinetic_ratio * tau_s, static_accel_m_s2, kinetic_ratio, area_m2, polar_m3,
                     second_moments_m4[0], second_moments_m4[1], rtol, mass_kg / (tau_s * area_m2),
                     inertia_kg_m2 / (tau_s * polar_m3)])  # fmt: skip


def initial_state(pose: tuple[float, float, float], radius_m: float) -> np.ndarray:
    """A part stuck at ``pose`` (plate frame)."""
    st = np.zeros(STATE_SIZE)
    st[STUCK] = 1.0
    st[POSE : POSE + 3] = pose
    st[RADIUS] = radius_m
    return st


# --- plate motion (:class:`.plate_motion.Segment`) -------------------------------------------


@_jit_inline
def _position(seg: np.ndarray, tau: float) -> tuple[float, float, float]:
    c = 0.0 if seg[KAPPA] == 0 else math.cos(seg[KAPPA] * tau) - 1.0
    return (seg[V] * tau + 0.5 * seg[A] * tau * tau + seg[C] * c,
            seg[V + 1] * tau + 0.5 * seg[A + 1] * tau * tau + seg[C + 1] * c,
            seg[V + 2] * tau + 0.5 * seg[A + 2] * tau * tau + seg[C + 2] * c)  # fmt: skip


@_jit_inline
def plate_velocity(seg: np.ndarray, tau: float) -> tuple[float, float, float]:
    s = 0.0 if seg[KAPPA] == 0 else -seg[KAPPA] * math.sin(seg[KAPPA] * tau)
    return (seg[V] + seg[A] * tau + seg[C] * s, seg[V + 1] + seg[A + 1] * tau + seg[C + 1] * s,
            seg[V + 2] + seg[A + 2] * tau + seg[C + 2] * s)  # fmt: skip


@_jit_inline
def plate_accel(seg: np.ndarray, tau: float) -> tuple[float, float, float]:
    c = 0.0 if seg[KAPPA] == 0 else -(seg[KAPPA] ** 2) * math.cos(seg[KAPPA] * tau)
    return seg[A] + seg[C] * c, seg[A + 1] + seg[C + 1] * c, seg[A + 2] + seg[C + 2] * c


@_jit
def is_smooth(seg: np.ndarray) -> bool:
    return seg[KAPPA] == 0 or (seg[C] == 0 and seg[C + 1] == 0 and seg[C + 2] == 0)


@_jit
def is_turning(seg: np.ndarray) -> bool:
    return seg[V + 2] != 0 or seg[A + 2] != 0 or seg[C + 2] != 0


@_jit_inline
def plate_at(seg: np.ndarray, plate: np.ndarray, tau: float) -> tuple[float, float, float]:
    d = _position(seg, tau)
    return plate[0] + d[0], plate[1] + d[1], plate[2] + d[2]


@_jit_inline
def finish_segment(seg: np.ndarray, plate: np.ndarray) -> None:
    """The plate at the segment's end: pose, velocity, elapsed time."""
    x, y, th = plate_at(seg, plate, seg[DURATION])
    vx, vy, om = plate_velocity(seg, seg[DURATION])
    plate[0], plate[1], plate[2], plate[3], plate[4], plate[5] = x, y, th, vx, vy, om
    plate[ELAPSED] += seg[DURATION]


_SMALL_TURN = 1e-2
"""Below this angle (rad) :func:`_turn` sums the series: the plate turns by ~1e-2 rad at most (stroke
over lever arm), and its pose is needed at every sample."""


@_jit_inline
def _turn(angle: float) -> tuple[float, float]:
    """(cos, sin) of ``angle``; below _SMALL_TURN the Taylor series to the 6th and 7th power (the
    next terms < 3e-21: to rounding, a few multiplications instead of the library's sincos)."""
    if abs(angle) >= _SMALL_TURN:
        return math.cos(angle), math.sin(angle)
    a2 = angle * angle
    return (1.0 - a2 * (0.5 - a2 * (1 / 24 - a2 / 720)),
            angle * (1.0 - a2 * (1 / 6 - a2 * (1 / 120 - a2 / 5040))))  # fmt: skip


@_jit
def plate_frame_pose(st: np.ndarray, px: float, py: float, pth: float) -> tuple[float, float, float]:
    """The part's pose in the plate frame, the plate at (px, py, pth)."""
    if st[STUCK] != 0:
        return st[POSE], st[POSE + 1], st[POSE + 2]
    c, s = _turn(pth)
    dx, dy = st[LAB] - px, st[LAB + 1] - py
    return c * dx + s * dy, -s * dx + c * dy, st[LAB + 2] - pth


@_jit_inline
def lab_pose_of(states: np.ndarray, i: int, px: float, py: float, pth: float) -> tuple[float, float, float]:
    """The pose of part i (a row of ``states``) in the lab frame, the plate at (px, py, pth): as
    :func:`lab_pose`, indexing the rows in place (numba's view of a row costs ~10–30 ns)."""
    if states[i, STUCK] == 0:
        return states[i, LAB], states[i, LAB + 1], states[i, LAB + 2]
    c, s = _turn(pth)
    x, y, psi = states[i, POSE], states[i, POSE + 1], states[i, POSE + 2]
    return px + c * x - s * y, py + s * x + c * y, pth + psi


@_jit
def lab_pose(st: np.ndarray, px: float, py: float, pth: float) -> tuple[float, float, float]:
    """The part's pose in the lab frame, the plate at (px, py, pth)."""
    return lab_pose_of(st.reshape(1, STATE_SIZE), 0, px, py, pth)


@_jit
def carry(st: np.ndarray, px: float, py: float, pth: float, vx: float, vy: float, om: float) -> None:
    """Lab state of the part moving rigidly with the plate."""
    cx, cy, phi = lab_pose(st, px, py, pth)
    rx, ry = cx - px, cy - py
    st[LAB], st[LAB + 1], st[LAB + 2] = cx, cy, phi
    st[LAB + 3], st[LAB + 4], st[LAB + 5] = vx - om * ry, vy + om * rx, om


@_jit_inline
def twist_dot(pp: np.ndarray, a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> float:
    return a0 * b0 + a1 * b1 + pp[INERTIA] / pp[MASS] * a2 * b2


@_jit_inline
def relative_twist(x: float, y: float, vx_part: float, vy_part: float, om_part: float, px: float, py: float,
           vx: float, vy: float, om: float) -> tuple[float, float, float]:  # fmt: skip
    """Relative twist (w_x, w_y lab; ω_r) of a part at (x, y) moving at (v, ω) on the plate."""
    rx, ry = x - px, y - py
    return vx_part - (vx - om * ry), vy_part - (vy + om * rx), om_part - om
