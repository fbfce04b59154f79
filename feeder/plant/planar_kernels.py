"""Compiled planar stick-slip (numba, extra ``fast``; plain Python without it): :mod:`.planar` on arrays.

The same event-driven solver as :class:`feeder.plant.planar._PartState` (the
reference, run when :func:`feeder.plant.kernels.enabled` is false), in scalar
code over float arrays so that numba compiles a whole segment, a whole
sampled chunk or a whole run: slip episodes by Dormand-Prince 5(4) (scipy's
RK45 step control, rtol 1e-10; the step size carries over from one segment to
the next within an episode), the twist's vanishing by the reference's
drop-and-shorten rule, breakaway by Brent's method, the limit-surface gauge by
BFGS.  Results agree with the reference to the integrators' tolerance
(tests/test_plant_kernels.py).

Arrays: a segment is ``SEG_SIZE`` floats (duration, velocity, acceleration,
cosine amplitude per axis, κ; :class:`.plate_motion.Segment`); the plate is
(x_O, y_O, θ, v_x, v_y, Ω, elapsed time); a part's parameters are
``PARAM_SIZE`` floats (:func:`part_params`); its state ``STATE_SIZE`` floats
(stuck, plate-frame pose, lab state while slipping, slip time, stop
threshold, last step size, fade step, Dormand-Prince steps tried so far, the derivative
carried to the next segment and where);
discs integrate over :data:`DISC_NODES` (unit disc: x, y, weight), scaled by
their radius.
"""

from __future__ import annotations

import math

import numpy as np

from feeder.plant.kernels import (
    DRIVE_STATES,
    DriveState,
    _jit,
    _jit_inline,
    contact_interval,
    drive_sample,
    rectangle_integrals,
)

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

_SEED_TIME_S = 1e-12
_STOP = 1e-10
_BREAKAWAY_SAMPLES = 16
_ROUNDING = 1e-14
_HELD_MARGIN = 1 - 1e-6
_ALIGNED = 0.9
_STRAIGHT = 0.5
"""A twist shrinking this straight (cosine of twist and its rate) fades in ln|twist| (:func:`_fade`)."""
_SERIES_BELOW = 1e-3
_MISS2 = 0.25
"""A twist whose linear closest approach stays above half its size (squared: this) turns, not vanishes."""
_NEAR_ZERO = 100.0
"""A turning twist this close to the stop threshold (factor) has vanished."""
_UNRESOLVED = 100.0
"""A shrinking twist within this many absolute error scales of the velocities (atol + rtol·|v|,
as the step control's) has vanished: below it the steps' error hides the twist's direction,
which then spins at ~|dξ/dt|/|ξ| and holds the steps at a stability limit, not at a turn."""
_ATOL = np.array([1e-6, 1e-6, 1e-3, 1e-3, 1e-3, 10.0, 1e-6])
"""Absolute tolerances per unit rtol of (c − c₀, φ − φ₀, v, ω, t): at rtol 1e-10 the
reference's (1e-16 m, ...), and 1e-16 s for the time (a part at 0.1 m/s: 1e-17 m)."""
_NO_DRAWS = np.zeros(0)
_EPS = float(np.finfo(np.float64).eps)

# Dormand-Prince 5(4) (scipy's RK45)
_C2, _C3, _C4, _C5 = 1 / 5, 3 / 10, 4 / 5, 8 / 9
_A21 = 1 / 5
_A31, _A32 = 3 / 40, 9 / 40
_A41, _A42, _A43 = 44 / 45, -56 / 15, 32 / 9
_A51, _A52, _A53, _A54 = 19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729
_A61, _A62, _A63, _A64, _A65 = 9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656
_B1, _B3, _B4, _B5, _B6 = 35 / 384, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84
_E1, _E3, _E4, _E5, _E6, _E7 = -71 / 57600, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40
_TABLEAU = np.array([[_A21, 0, 0, 0, 0, 0], [_A31, _A32, 0, 0, 0, 0], [_A41, _A42, _A43, 0, 0, 0],
                     [_A51, _A52, _A53, _A54, 0, 0], [_A61, _A62, _A63, _A64, _A65, 0],
                     [_B1, 0.0, _B3, _B4, _B5, _B6]])  # fmt: skip
"""Rows: the stages' coefficients of k1 … k6 (the last: the 5th-order solution, B2 = 0 adds exact zeros)."""


def _unit_disc_nodes(radial: int = 48, angular: int = 96) -> np.ndarray:
    """(3, radial·angular): x, y, weight of the polar Gauss rule on the unit disc (as :class:`.Patch`)."""
    g, gw = np.polynomial.legendre.leggauss(radial)
    r = 0.5 * (g + 1)
    phi = 2 * np.pi * (np.arange(angular) + 0.5) / angular
    weight = np.outer(0.5 * gw * r, np.full(angular, 2 * np.pi / angular))
    return np.array([np.outer(r, np.cos(phi)).ravel(), np.outer(r, np.sin(phi)).ravel(), weight.ravel()])


DISC_NODES = _unit_disc_nodes()


def part_params(disc: bool, length_m: float, width_m: float, mass_kg: float, inertia_kg_m2: float,
                static_accel_m_s2: float, kinetic_ratio: float, area_m2: float, polar_m3: float,
                second_moments_m4: tuple[float, float], rtol: float) -> np.ndarray:  # fmt: skip
    """A part's parameter row (τ_s = m·a_s/A, τ_k = r·τ_s as :class:`.planar._PartState`; rtol
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
def _velocity(seg: np.ndarray, tau: float) -> tuple[float, float, float]:
    s = 0.0 if seg[KAPPA] == 0 else -seg[KAPPA] * math.sin(seg[KAPPA] * tau)
    return (seg[V] + seg[A] * tau + seg[C] * s, seg[V + 1] + seg[A + 1] * tau + seg[C + 1] * s,
            seg[V + 2] + seg[A + 2] * tau + seg[C + 2] * s)  # fmt: skip


@_jit_inline
def _accel(seg: np.ndarray, tau: float) -> tuple[float, float, float]:
    c = 0.0 if seg[KAPPA] == 0 else -(seg[KAPPA] ** 2) * math.cos(seg[KAPPA] * tau)
    return seg[A] + seg[C] * c, seg[A + 1] + seg[C + 1] * c, seg[A + 2] + seg[C + 2] * c


@_jit
def _smooth(seg: np.ndarray) -> bool:
    return seg[KAPPA] == 0 or (seg[C] == 0 and seg[C + 1] == 0 and seg[C + 2] == 0)


@_jit
def _turns(seg: np.ndarray) -> bool:
    return seg[V + 2] != 0 or seg[A + 2] != 0 or seg[C + 2] != 0


@_jit_inline
def _plate_at(seg: np.ndarray, plate: np.ndarray, tau: float) -> tuple[float, float, float]:
    d = _position(seg, tau)
    return plate[0] + d[0], plate[1] + d[1], plate[2] + d[2]


@_jit_inline
def finish_segment(seg: np.ndarray, plate: np.ndarray) -> None:
    """The plate at the segment's end: pose, velocity, elapsed time."""
    x, y, th = _plate_at(seg, plate, seg[DURATION])
    vx, vy, om = _velocity(seg, seg[DURATION])
    plate[0], plate[1], plate[2], plate[3], plate[4], plate[5] = x, y, th, vx, vy, om
    plate[ELAPSED] += seg[DURATION]


# --- the limit surface (:class:`.limit_surface.Patch`) -----------------------------------------


@_jit_inline
def integrals(pp: np.ndarray, radius: float, nodes: np.ndarray, wx: float, wy: float,
              omega: float) -> tuple[float, float, float, float]:  # fmt: skip
    """:meth:`.Patch.integrals`: ∫v̂ dA, ∫ρ×v̂ dA, ∫|v| dA for the twist (w, ω), part frame."""
    speed = math.sqrt(wx * wx + wy * wy)  # glibc hypot: ~20 ns a call
    if speed == 0 and omega == 0:
        return 0.0, 0.0, 0.0, 0.0
    if abs(omega) * radius < _SERIES_BELOW * speed:
        ux, uy = wx / speed, wy / speed
        q = ux * ux * pp[JXX] + uy * uy * pp[JYY]
        area = pp[AREA]
        return area * ux, area * uy, omega * q / speed, speed * area + 0.5 * omega**2 * q / speed
    if pp[DISC] == 0:
        return rectangle_integrals(wx, wy, omega, pp[HALF_A], pp[HALF_B])
    r = pp[HALF_A]
    sx = sy = sm = sp = 0.0
    for i in range(nodes.shape[1]):
        x, y, weight = r * nodes[0, i], r * nodes[1, i], r * r * nodes[2, i]
        vx, vy = wx - omega * y, wy + omega * x
        v = math.sqrt(vx * vx + vy * vy)
        if v > 0:
            sx += weight * vx / v
            sy += weight * vy / v
            sm += weight * (x * vy - y * vx) / v
            sp += weight * v
    return sx, sy, sm, sp


@_jit
def _ratio(pp: np.ndarray, radius: float, nodes: np.ndarray, fx: float, fy: float, moment: float,
           scale: float, x: np.ndarray, grad: np.ndarray) -> float:  # fmt: skip
    """−W·ξ/∫|v_ξ|dA at the scaled twist x (ξ = (x₀, x₁, x₂/scale)); its gradient into ``grad``."""
    wx, wy, omega = x[0], x[1], x[2] / scale
    ux, uy, mu, power = integrals(pp, radius, nodes, wx, wy, omega)
    work = fx * wx + fy * wy + moment * omega
    grad[0] = -(fx - work * ux / power) / power
    grad[1] = -(fy - work * uy / power) / power
    grad[2] = -(moment - work * mu / power) / scale / power
    return -work / power


@_jit
def gauge(pp: np.ndarray, radius: float, nodes: np.ndarray, fx: float, fy: float,
          moment: float) -> tuple[float, float, float, float]:  # fmt: skip
    """:meth:`.Patch.gauge`: (g(W), ξ_x, ξ_y, ξ_ω), the maximum of W·ξ/∫|v_ξ|dA by BFGS."""
    force = math.hypot(fx, fy)
    if force == 0 and moment == 0:
        return 0.0, 0.0, 0.0, 0.0
    if moment == 0:
        return force / pp[AREA], fx / force, fy / force, 0.0
    if force == 0:
        return abs(moment) / pp[POLAR], 0.0, 0.0, math.copysign(1.0, moment)
    area, polar = pp[AREA], pp[POLAR]
    scale = polar / area
    x = np.array([fx / area**2, fy / area**2, scale * moment / polar**2])
    x /= math.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2)
    grad, trial, grad_trial = np.empty(3), np.empty(3), np.empty(3)
    f = _ratio(pp, radius, nodes, fx, fy, moment, scale, x, grad)
    h = np.eye(3)
    first = True
    for _ in range(200):
        if math.sqrt(grad @ grad) <= 1e-12 * abs(f):  # |x| stays ~1: a relative gradient
            break
        p = -(h @ grad)
        slope = p @ grad
        if slope >= 0:  # not a descent direction: restart from the steepest descent
            h = np.eye(3)
            p = -grad.copy()
            slope = p @ grad
        step = min(1.0, 0.1 / math.sqrt(p @ p)) if first else 1.0
        f_trial = f
        for _ in range(60):  # backtracking (Armijo)
            trial[:] = x + step * p
            f_trial = _ratio(pp, radius, nodes, fx, fy, moment, scale, trial, grad_trial)
            if f_trial <= f + 1e-4 * step * slope:
                break
            step *= 0.5
        if not f_trial < f:  # no decrease within rounding: converged
            break
        s = trial - x
        y = grad_trial - grad
        sy = s @ y
        if sy > 0:
            if first:
                h = np.eye(3) * (sy / (y @ y))
            rho = 1.0 / sy
            hy = h @ y
            h = h + ((sy + y @ hy) * rho * rho) * np.outer(s, s) - rho * (np.outer(hy, s) + np.outer(s, hy))
        first = False
        x[:] = trial
        grad[:] = grad_trial
        f = f_trial
    return -f, x[0], x[1], x[2] / scale


@_jit
def holds(pp: np.ndarray, radius: float, nodes: np.ndarray, fx: float, fy: float, moment: float) -> bool:
    """:meth:`.Patch.holds` at τ_s: the diamond, the cylinder, then the gauge."""
    stress = pp[TAU_S]
    f = math.hypot(fx, fy) / (stress * pp[AREA])
    m = abs(moment) / (stress * pp[POLAR])
    if f + m <= 1:
        return True
    if f > 1 or m > 1:
        return False
    return gauge(pp, radius, nodes, fx, fy, moment)[0] <= stress


# --- one part (:class:`.planar._PartState`) ----------------------------------------------------


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
def _lab_pose_of(states: np.ndarray, i: int, px: float, py: float, pth: float) -> tuple[float, float, float]:
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
    return _lab_pose_of(st.reshape(1, STATE_SIZE), 0, px, py, pth)


@_jit
def _carry(st: np.ndarray, px: float, py: float, pth: float, vx: float, vy: float, om: float) -> None:
    """Lab state of the part moving rigidly with the plate."""
    cx, cy, phi = lab_pose(st, px, py, pth)
    rx, ry = cx - px, cy - py
    st[LAB], st[LAB + 1], st[LAB + 2] = cx, cy, phi
    st[LAB + 3], st[LAB + 4], st[LAB + 5] = vx - om * ry, vy + om * rx, om


@_jit
def _required(st: np.ndarray, pp: np.ndarray, seg: np.ndarray, plate: np.ndarray,
              tau: float) -> tuple[float, float, float]:  # fmt: skip
    """Wrench (F_x, F_y, M) in the part frame that carries the stuck part at τ."""
    px, py, pth = _plate_at(seg, plate, tau)
    om = _velocity(seg, tau)[2]
    ax, ay, alpha = _accel(seg, tau)
    cx, cy, phi = lab_pose(st, px, py, pth)
    rx, ry = cx - px, cy - py
    om2 = om * om
    m = pp[MASS]
    fx, fy = m * (ax - alpha * ry - om2 * rx), m * (ay + alpha * rx - om2 * ry)
    c, s = math.cos(phi), math.sin(phi)
    return c * fx + s * fy, -s * fx + c * fy, pp[INERTIA] * alpha


@_jit_inline
def _dot(pp: np.ndarray, a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> float:
    return a0 * b0 + a1 * b1 + pp[INERTIA] / pp[MASS] * a2 * b2


@_jit_inline
def _twist(x: float, y: float, vx_part: float, vy_part: float, om_part: float, px: float, py: float,
           vx: float, vy: float, om: float) -> tuple[float, float, float]:  # fmt: skip
    """Relative twist (w_x, w_y lab; ω_r) of a part at (x, y) moving at (v, ω) on the plate."""
    rx, ry = x - px, y - py
    return vx_part - (vx - om * ry), vy_part - (vy + om * rx), om_part - om


@_jit
def _seed(st: np.ndarray, pp: np.ndarray, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
          tau: float) -> None:  # fmt: skip
    """Start a slip from (near) zero twist along the breakaway direction of the required wrench."""
    fx, fy, m = _required(st, pp, seg, plate, tau)
    _, wx, wy, om = gauge(pp, st[RADIUS], nodes, fx, fy, m)
    c, s = math.cos(st[LAB + 2]), math.sin(st[LAB + 2])
    lx, ly = c * wx - s * wy, s * wx + c * wy
    size = math.sqrt(_dot(pp, lx, ly, om, lx, ly, om))
    speed = pp[A_S] * _SEED_TIME_S / size
    st[LAB + 3] -= speed * lx
    st[LAB + 4] -= speed * ly
    st[LAB + 5] -= speed * om
    st[STOP] = 0.01 * speed * size
    st[STEP] = 0.0


@_jit
def _excess(st: np.ndarray, pp: np.ndarray, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
            tau: float) -> float:  # fmt: skip
    fx, fy, m = _required(st, pp, seg, plate, tau)
    return gauge(pp, st[RADIUS], nodes, fx, fy, m)[0] - pp[TAU_S]


@_jit
def _brent(st: np.ndarray, pp: np.ndarray, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
           xa: float, xb: float, xtol: float) -> float:  # fmt: skip
    """Root of :func:`_excess` in [xa, xb] (scipy's brentq, rtol 4·eps)."""
    rtol = 4 * _EPS
    xpre, xcur, xblk = xa, xb, 0.0
    fpre, fcur, fblk = _excess(st, pp, nodes, seg, plate, xa), _excess(st, pp, nodes, seg, plate, xb), 0.0
    spre = scur = 0.0
    if fpre == 0:
        return xpre
    if fcur == 0:
        return xcur
    if fpre * fcur > 0:
        raise RuntimeError("planar stick-slip: breakaway not bracketed")
    for _ in range(100):
        if fpre != 0 and fcur != 0 and (fpre < 0) != (fcur < 0):
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        delta = 0.5 * (xtol + rtol * abs(xcur))
        sbis = 0.5 * (xblk - xcur)
        if fcur == 0 or abs(sbis) < delta:
            return xcur
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:
                stry = -fcur * (xcur - xpre) / (fcur - fpre)
            else:
                dpre = (fpre - fcur) / (xpre - xcur)
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            if 2 * abs(stry) < min(abs(spre), 3 * abs(sbis) - delta):
                spre, scur = scur, stry
            else:
                spre = scur = sbis
        else:
            spre = scur = sbis
        xpre, fpre = xcur, fcur
        xcur += scur if abs(scur) > delta else (delta if sbis > 0 else -delta)
        fcur = _excess(st, pp, nodes, seg, plate, xcur)
    return xcur


@_jit
def _breakaway(st: np.ndarray, pp: np.ndarray, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
               tau: float) -> float:  # fmt: skip
    """First time ≥ τ in the segment where the static limit surface no longer holds the part; −1 if none."""
    smooth = _smooth(seg)
    if smooth and not _turns(seg):  # constant wrench m·a, a pure force
        return tau if math.hypot(seg[A], seg[A + 1]) > pp[A_S] else -1.0
    times = np.linspace(tau, seg[DURATION], 2 if smooth else _BREAKAWAY_SAMPLES + 1)
    before = tau
    for t in times:
        fx, fy, m = _required(st, pp, seg, plate, t)
        if not holds(pp, st[RADIUS], nodes, fx, fy, m):
            if t == tau:
                return tau
            return _brent(st, pp, nodes, seg, plate, before, t, 1e-15 * seg[DURATION])
        before = t
    return -1.0


@_jit_inline
def _rhs(pp: np.ndarray, radius: float, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
         x0: float, y0: float, phi0: float, t: float, y: np.ndarray, out: np.ndarray) -> None:  # fmt: skip
    """Rigid-body motion under kinetic friction; y = (c − c₀, φ − φ₀, v, ω), lab frame."""
    px, py, _ = _plate_at(seg, plate, t)
    vx, vy, om = _velocity(seg, t)
    rx, ry = x0 + y[0] - px, y0 + y[1] - py
    wx, wy = y[3] - (vx - om * ry), y[4] - (vy + om * rx)
    phi = phi0 + y[2]
    c, s = math.cos(phi), math.sin(phi)
    ux, uy, mu, _ = integrals(pp, radius, nodes, c * wx + s * wy, -s * wx + c * wy, y[5] - om)
    tau_k, m = pp[TAU_K], pp[MASS]
    out[0], out[1], out[2] = y[3], y[4], y[5]
    out[3] = -tau_k * (c * ux - s * uy) / m
    out[4] = -tau_k * (s * ux + c * uy) / m
    out[5] = -tau_k * mu / pp[INERTIA]


@_jit_inline
def _rel_twist(seg: np.ndarray, plate: np.ndarray, x0: float, y0: float, t: float,
               y: np.ndarray) -> tuple[float, float, float]:  # fmt: skip
    px, py, _ = _plate_at(seg, plate, t)
    vx, vy, om = _velocity(seg, t)
    return _twist(x0 + y[0], y0 + y[1], y[3], y[4], y[5], px, py, vx, vy, om)


@_jit_inline
def _twist_rate(seg: np.ndarray, plate: np.ndarray, x0: float, y0: float, t: float, y: np.ndarray,
                f: np.ndarray) -> tuple[float, float, float]:  # fmt: skip
    """d(w, ω_r)/dt = (dv/dt − a_plate(c) − Ω ẑ×w, dω/dt − α), f the state's derivative."""
    px, py, _ = _plate_at(seg, plate, t)
    om = _velocity(seg, t)[2]
    ax, ay, alpha = _accel(seg, t)
    rx, ry = x0 + y[0] - px, y0 + y[1] - py
    wx, wy, _ = _rel_twist(seg, plate, x0, y0, t, y)
    return (f[3] - (ax - alpha * ry - om * om * rx) + om * wy,
            f[4] - (ay + alpha * rx - om * om * ry) - om * wx, f[5] - alpha)  # fmt: skip


@_jit_inline
def _derivative(sigma: bool, pp: np.ndarray, radius: float, nodes: np.ndarray, seg: np.ndarray,
                plate: np.ndarray, x0: float, y0: float, phi0: float, z: np.ndarray,
                out: np.ndarray) -> bool:  # fmt: skip
    """dz/ds for z = (y, t): s is t itself, or with ``sigma`` s = −ln|twist| (dt/ds = −|ξ|²/(ξ·dξ/dt)).

    False (in ``sigma``) where the twist does not shrink nearly straight (the cosine of
    twist and rate below _STRAIGHT): near a turn of |twist|, s is no coordinate.
    """
    t = z[6]
    _rhs(pp, radius, nodes, seg, plate, x0, y0, phi0, t, z, out)
    if not sigma:
        out[6] = 1.0
        return True
    p0, p1, p2 = _rel_twist(seg, plate, x0, y0, t, z)
    d0, d1, d2 = _twist_rate(seg, plate, x0, y0, t, z, out)
    shrink = _dot(pp, p0, p1, p2, d0, d1, d2)
    size2 = _dot(pp, p0, p1, p2, p0, p1, p2)
    if not shrink < -_STRAIGHT * math.sqrt(size2 * _dot(pp, d0, d1, d2, d0, d1, d2)):
        return False
    q = -size2 / shrink
    for i in range(6):
        out[i] *= q
    out[6] = q
    return True


@_jit
def _dp5_step(sigma: bool, pp: np.ndarray, radius: float, nodes: np.ndarray, seg: np.ndarray,
              plate: np.ndarray, x0: float, y0: float, phi0: float, z: np.ndarray, h: float,
              ks: np.ndarray, z_new: np.ndarray) -> float:  # fmt: skip
    """One Dormand-Prince 5(4) step of size h from z (ks[0] = dz/ds there) into z_new, ks[6] =
    dz/ds at z_new (ks[7]: scratch); returns the RMS error relative to atol + rtol·|z| (scipy's
    RK45), inf if invalid."""
    for stage in range(6):  # one call site: _derivative is inlined once, not six times
        row = _TABLEAU[stage]
        w = z_new if stage == 5 else ks[7]
        for i in range(7):
            if stage == 0:
                w[i] = z[i] + h * _A21 * ks[0, i]
                continue
            acc = row[0] * ks[0, i]
            for j in range(1, stage + 1):
                acc += row[j] * ks[j, i]
            w[i] = z[i] + h * acc
        if not _derivative(sigma, pp, radius, nodes, seg, plate, x0, y0, phi0, w, ks[stage + 1]):
            return np.inf
    k1, k3, k4, k5, k6, k7 = ks[0], ks[2], ks[3], ks[4], ks[5], ks[6]
    total = 0.0
    for i in range(7):
        err = h * (_E1 * k1[i] + _E3 * k3[i] + _E4 * k4[i] + _E5 * k5[i] + _E6 * k6[i] + _E7 * k7[i])
        total += (err / ((_ATOL[i] + max(abs(z[i]), abs(z_new[i]))) * pp[RTOL])) ** 2
    return math.sqrt(total / 7)


@_jit
def _initial_step(pp: np.ndarray, radius: float, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
                  x0: float, y0: float, phi0: float, z: np.ndarray, f: np.ndarray,
                  interval: float) -> float:  # fmt: skip
    """scipy's ``select_initial_step`` (error estimator of order 4), in time."""
    d0 = d1 = 0.0
    for i in range(6):
        scale = (_ATOL[i] + abs(z[i])) * pp[RTOL]
        d0 += (z[i] / scale) ** 2
        d1 += (f[i] / scale) ** 2
    d0, d1 = math.sqrt(d0 / 6), math.sqrt(d1 / 6)
    h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
    h0 = min(h0, interval)
    f1 = np.empty(7)
    _derivative(False, pp, radius, nodes, seg, plate, x0, y0, phi0, z + h0 * f, f1)
    d2 = 0.0
    for i in range(6):
        d2 += ((f1[i] - f[i]) / ((_ATOL[i] + abs(z[i])) * pp[RTOL])) ** 2
    d2 = math.sqrt(d2 / 6) / h0
    h1 = max(1e-6, h0 * 1e-3) if d1 <= 1e-15 and d2 <= 1e-15 else (0.01 / max(d1, d2)) ** 0.2
    return min(100 * h0, h1, interval)


_STOPPED, _LEFT, _NEAR_END = 0, 1, 2


@_jit
def _fade(st: np.ndarray, pp: np.ndarray, radius: float, nodes: np.ndarray, seg: np.ndarray,
          plate: np.ndarray, x0: float, y0: float, phi0: float, z: np.ndarray, target: float,
          ks: np.ndarray) -> int:  # fmt: skip
    """A shrinking twist down to ``target`` in s = −ln|twist| (z updated); returns how it ended.

    Near a re-stick the sliding direction turns at a rate ∝ 1/|twist|, so steps
    in time shrink with the time left; in ln|twist| the motion is smooth and
    the stop threshold is a fixed end point.  _STOPPED: the twist reached
    ``target``; _NEAR_END: the segment ends within the next step; _LEFT: the
    twist stopped shrinking straight (both continue in time).  The step size
    carries over.
    """
    t_end = seg[DURATION]
    p0, p1, p2 = _rel_twist(seg, plate, x0, y0, z[6], z)
    size = math.sqrt(_dot(pp, p0, p1, p2, p0, p1, p2))
    if not size > target:
        return _STOPPED
    args = (pp, radius, nodes, seg, plate, x0, y0, phi0)
    if not _derivative(True, pp, radius, nodes, seg, plate, x0, y0, phi0, z, ks[0]):
        return _LEFT
    z_new = np.empty(7)
    s, s_end = 0.0, math.log(size / target)
    h = st[FADE_STEP] if st[FADE_STEP] > 0 else 1.0
    for _ in range(100_000):
        h = min(h, s_end - s)
        norm = _dp5_step(True, *args, z, h, ks, z_new)
        st[STEPS] += 1
        if norm == np.inf:  # a stage where the twist turns
            h *= 0.25
            if h < 1e-2:  # turning: it will not vanish straight, continue in time
                return _LEFT
            continue
        if norm >= 1:
            h *= max(0.2, 0.9 * norm**-0.2)
            continue
        grow = 10.0 if norm == 0 else min(10.0, 0.9 * norm**-0.2)
        if z_new[6] > t_end:  # the segment ends within the step: its rest in time
            st[FADE_STEP] = h
            return _NEAR_END
        s = s_end if h >= s_end - s else s + h
        z[:] = z_new
        ks[0, :] = ks[6]
        if s >= s_end:
            st[FADE_STEP] = h
            return _STOPPED
        h *= grow
    raise RuntimeError("planar stick-slip: the twist does not fade")


@_jit_inline
def _resolution(pp: np.ndarray, z: np.ndarray) -> float:
    """The step control's absolute error scale of the twist ((atol + rtol·|v|) per velocity, m/s)."""
    r0, r1, r2 = ((_ATOL[3] + abs(z[3])) * pp[RTOL], (_ATOL[4] + abs(z[4])) * pp[RTOL],
                  (_ATOL[5] + abs(z[5])) * pp[RTOL])  # fmt: skip
    return math.sqrt(_dot(pp, r0, r1, r2, r0, r1, r2))


@_jit_inline
def _shrinks(seg: np.ndarray, plate: np.ndarray, x0: float, y0: float, pp: np.ndarray, z: np.ndarray,
             f: np.ndarray, w0: float, w1: float, w2: float) -> bool:  # fmt: skip
    """Whether the twist (w) at z, f = dz/dt, shrinks."""
    d0, d1, d2 = _twist_rate(seg, plate, x0, y0, z[6], z, f)
    return _dot(pp, w0, w1, w2, d0, d1, d2) < 0


@_jit
def _integrate(st: np.ndarray, pp: np.ndarray, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
               x0: float, y0: float, phi0: float, t: float, y: np.ndarray,
               carried: bool) -> tuple[float, bool]:  # fmt: skip
    """From t towards the segment's end until the twist vanishes; y updated, returns (time, vanished).

    In time (scipy's RK45 step control) while the twist grows, as
    :meth:`.planar._PartState._integrate` (a step that reverses the twist is
    dropped and the integration aims at 0.9 of the linearly predicted time to
    zero); in ln|twist| (:func:`_fade`) once it shrinks faster than the steps
    in time can follow.  Ends at the same threshold: the twist below _STOP of
    its start (or at the velocities' rounding floor).  A near miss (the
    linear closest approach above half the twist) goes on in time, as the
    reference.  ``carried``: the derivative at t is the one stored at the
    previous segment's end (:data:`DERIV`), else evaluated; stored again if the
    slip reaches this segment's end.
    """
    radius, t_end = st[RADIUS], seg[DURATION]
    stop = st[STOP]
    ks = np.empty((8, 7))
    z, z_new = np.empty(7), np.empty(7)
    z[:6] = y
    z[6] = t
    args = (pp, radius, nodes, seg, plate, x0, y0, phi0)
    bound = t_end
    p0, p1, p2 = _rel_twist(seg, plate, x0, y0, t, z)
    factor = 0.9
    h_abs = st[STEP]
    h = 0.0
    fade = True
    if carried:
        ks[0, :6] = st[DERIV : DERIV + 6]
        ks[0, 6] = 1.0
    else:
        _derivative(False, pp, radius, nodes, seg, plate, x0, y0, phi0, z, ks[0])
    for _ in range(1000):
        begin = z[6]
        reversed_ = False
        while z[6] < bound:
            d0, d1, d2 = _twist_rate(seg, plate, x0, y0, z[6], z, ks[0])
            shrink = _dot(pp, p0, p1, p2, d0, d1, d2)
            size2 = _dot(pp, p0, p1, p2, p0, p1, p2)
            aligned = shrink < -_ALIGNED * math.sqrt(size2 * _dot(pp, d0, d1, d2, d0, d1, d2))
            if fade and aligned and -size2 / shrink < 2 * (t_end - z[6]):  # it vanishes in this segment
                floor = _ROUNDING * math.sqrt(_dot(pp, z[3], z[4], z[5], z[3], z[4], z[5]))
                ended = _fade(st, pp, radius, nodes, seg, plate, x0, y0, phi0, z, max(stop, floor), ks)
                y[:] = z[:6]
                if ended == _STOPPED:
                    return z[6], True
                p0, p1, p2 = _rel_twist(seg, plate, x0, y0, z[6], z)
                _derivative(False, pp, radius, nodes, seg, plate, x0, y0, phi0, z, ks[0])
                fade = False
                if ended == _NEAR_END:  # try the rest of the segment in one step
                    h_abs = bound - z[6]
                continue
            if h_abs <= 0:  # scipy's guess, at most the twist's own time scale |ξ|/|dξ/dt| (a seed: ~1e-12 s)
                h_abs = _initial_step(*args, z, ks[0], bound - z[6])
                rate2 = _dot(pp, d0, d1, d2, d0, d1, d2)
                if rate2 > 0 and size2 > 0:
                    h_abs = min(h_abs, math.sqrt(size2 / rate2))
            min_step = 10 * _EPS * abs(z[6])
            rejected = False
            while True:  # one accepted step (scipy's RK45 step control)
                if h_abs < min_step:
                    raise RuntimeError("planar stick-slip: integration step too small")
                t_new = min(z[6] + h_abs, bound)
                h = t_new - z[6]
                norm = _dp5_step(False, *args, z, h, ks, z_new)
                st[STEPS] += 1
                if norm < 1:
                    grow = 10.0 if norm == 0 else min(10.0, 0.9 * norm**-0.2)
                    if rejected:
                        grow = min(1.0, grow)
                    # a step cut short by the bound keeps the size the error allowed
                    h_abs = max(h * grow, h_abs) if t_new == bound and not rejected else h * grow
                    break
                h_abs = h * max(0.2, 0.9 * norm**-0.2)  # of the step tried (scipy: a clipped step)
                rejected = True
            z_new[6] = t_new
            n0, n1, n2 = _rel_twist(seg, plate, x0, y0, t_new, z_new)
            if _dot(pp, n0, n1, n2, p0, p1, p2) <= 0:
                reversed_ = True
                break
            z[:] = z_new
            ks[0, :] = ks[6]
            p0, p1, p2 = n0, n1, n2
            fade = True
            floor = _ROUNDING * math.sqrt(_dot(pp, z[3], z[4], z[5], z[3], z[4], z[5]))
            size = math.sqrt(_dot(pp, n0, n1, n2, n0, n1, n2))
            lost = size <= _UNRESOLVED * _resolution(pp, z) and _shrinks(seg, plate, x0, y0, pp, z, ks[0],
                                                                          n0, n1, n2)  # fmt: skip
            if size <= max(stop, floor) or lost:
                y[:] = z[:6]
                st[STEP] = h_abs
                return z[6], True
        y[:] = z[:6]
        t = z[6]
        if not reversed_ and t >= t_end:
            st[STEP] = h_abs
            st[DERIV : DERIV + 6] = ks[0, :6]
            st[DERIV_AT] = plate[ELAPSED] + t_end  # as finish_segment adds it
            return t, False
        d0, d1, d2 = _twist_rate(seg, plate, x0, y0, t, z, ks[0])
        size2 = _dot(pp, p0, p1, p2, p0, p1, p2)
        rate2 = _dot(pp, d0, d1, d2, d0, d1, d2)
        along = _dot(pp, p0, p1, p2, d0, d1, d2)
        to_zero = -along / rate2 if rate2 > 0 else 0.0
        if not to_zero > 0 or size2 - along * along / rate2 >= _MISS2 * size2:
            # the twist turns rather than vanishes (a near miss): on in time, steps within its turn
            floor = _ROUNDING * math.sqrt(_dot(pp, z[3], z[4], z[5], z[3], z[4], z[5]))
            if math.sqrt(size2) <= _NEAR_ZERO * max(stop, floor):
                st[STEP] = h_abs
                return t, True
            bound = t_end
            if reversed_:
                h_abs = 0.5 * min(h, math.sqrt(size2 / rate2)) if rate2 > 0 else 0.5 * h
            continue
        factor = 0.9 if t > begin else 0.5 * factor
        if factor * to_zero <= 1e-15 * t_end:
            st[STEP] = h_abs
            return t, True
        bound = min(t_end, t + factor * to_zero)
        h_abs = 0.0  # a fresh start towards the new bound, as the reference
    raise RuntimeError("planar stick-slip: the twist does not vanish")


@_jit
def _settle(st: np.ndarray, pp: np.ndarray, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
            tau: float) -> None:  # fmt: skip
    """The twist has vanished at τ: sticks if the static surface holds it, else slips on."""
    px, py, pth = _plate_at(seg, plate, tau)
    st[POSE], st[POSE + 1], st[POSE + 2] = plate_frame_pose(st, px, py, pth)
    st[STUCK] = 1.0
    fx, fy, m = _required(st, pp, seg, plate, tau)
    if not holds(pp, st[RADIUS], nodes, fx, fy, m):
        vx, vy, om = _velocity(seg, tau)
        _carry(st, px, py, pth, vx, vy, om)
        st[STUCK] = 0.0
        _seed(st, pp, nodes, seg, plate, tau)


@_jit
def _slip_straight(st: np.ndarray, pp: np.ndarray, seg: np.ndarray, plate: np.ndarray, tau: float,
                   w0: float, w1: float) -> float:  # fmt: skip
    """Sliding along a fixed line: the 1-D closed form (DESIGN §4) along that line."""
    a0, a1 = seg[A], seg[A + 1]
    speed = math.hypot(w0, w1)
    ex, ey = (w0 / speed, w1 / speed) if speed else (a0, a1)
    norm = math.hypot(ex, ey)
    if norm == 0:
        px, py, pth = _plate_at(seg, plate, tau)
        st[POSE], st[POSE + 1], st[POSE + 2] = plate_frame_pose(st, px, py, pth)
        st[STUCK] = 1.0
        return tau
    ex, ey = ex / norm, ey / norm
    w_along, a_along = w0 * ex + w1 * ey, a0 * ex + a1 * ey
    a_s = pp[A_S]
    if w_along == 0 and abs(a_along) <= a_s:  # at rest relative to a plate it can follow
        stuck, rel, s, slip = True, 0.0, 0.0, 0.0
    else:
        stuck, rel, s, slip, _, _ = contact_interval(False, w_along, 0.0, 0.0, a_s, 0, a_along,
                                                     seg[DURATION] - tau, 0.0, a_s, pp[RATIO], 0.0,
                                                     _NO_DRAWS)  # fmt: skip
    q0x, q0y, _ = _plate_at(seg, plate, tau)
    q1x, q1y, q1th = _plate_at(seg, plate, seg[DURATION])
    v1x, v1y, _ = _velocity(seg, seg[DURATION])
    st[LAB] = st[LAB] + (q1x - q0x) + s * ex
    st[LAB + 1] = st[LAB + 1] + (q1y - q0y) + s * ey
    st[LAB + 3], st[LAB + 4], st[LAB + 5] = v1x + rel * ex, v1y + rel * ey, 0.0
    st[SLIP] += slip
    if stuck:
        st[POSE], st[POSE + 1], st[POSE + 2] = plate_frame_pose(st, q1x, q1y, q1th)
        st[STUCK] = 1.0
    return seg[DURATION]


@_jit
def _slip(st: np.ndarray, pp: np.ndarray, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
          tau: float) -> float:  # fmt: skip
    """Slip from τ to the re-stick time or the segment's end; returns the time reached."""
    px, py, _ = _plate_at(seg, plate, tau)
    vx, vy, om = _velocity(seg, tau)
    w0, w1, w2 = _twist(st[LAB], st[LAB + 1], st[LAB + 3], st[LAB + 4], st[LAB + 5], px, py, vx, vy, om)
    if _smooth(seg) and not _turns(seg) and w2 == 0 and w0 * seg[A + 1] == w1 * seg[A]:
        return _slip_straight(st, pp, seg, plate, tau, w0, w1)
    x0, y0, phi0 = st[LAB], st[LAB + 1], st[LAB + 2]
    y = np.array([0.0, 0.0, 0.0, st[LAB + 3], st[LAB + 4], st[LAB + 5]])
    carried = (tau == 0 and st[DERIV_AT] > 0 and st[DERIV_AT] == plate[ELAPSED] and seg[V] == plate[3]
               and seg[V + 1] == plate[4] and seg[V + 2] == plate[5])  # fmt: skip
    st[DERIV_AT] = 0.0
    end, stopped = _integrate(st, pp, nodes, seg, plate, x0, y0, phi0, tau, y, carried)
    st[LAB], st[LAB + 1], st[LAB + 2] = x0 + y[0], y0 + y[1], phi0 + y[2]
    st[LAB + 3], st[LAB + 4], st[LAB + 5] = y[3], y[4], y[5]
    st[SLIP] += end - tau
    if stopped:
        _settle(st, pp, nodes, seg, plate, end)
    return end


@_jit
def run_segment(
    st: np.ndarray, pp: np.ndarray, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray
) -> None:
    """One part through ``seg``; ``plate`` holds the plate at its start and the velocity before."""
    tau = 0.0
    px, py, pth = plate[0], plate[1], plate[2]
    corner = seg[V] != plate[3] or seg[V + 1] != plate[4] or seg[V + 2] != plate[5]
    if corner and st[STUCK] != 0:  # the part cannot follow
        _carry(st, px, py, pth, plate[3], plate[4], plate[5])
        st[STUCK] = 0.0
        w0, w1, w2 = _twist(st[LAB], st[LAB + 1], st[LAB + 3], st[LAB + 4], st[LAB + 5], px, py,
                            seg[V], seg[V + 1], seg[V + 2])  # fmt: skip
        st[STOP] = _STOP * math.sqrt(_dot(pp, w0, w1, w2, w0, w1, w2))
        st[STEP] = 0.0
    for _ in range(10_000):
        if tau >= seg[DURATION]:
            return
        if st[STUCK] != 0:
            start = _breakaway(st, pp, nodes, seg, plate, tau)
            if start < 0:
                return
            tau = start
            qx, qy, qth = _plate_at(seg, plate, tau)
            vx, vy, om = _velocity(seg, tau)
            _carry(st, qx, qy, qth, vx, vy, om)
            st[STUCK] = 0.0
            st[STEP] = 0.0
            if _turns(seg) or not _smooth(seg):  # else the 1-D closed form starts it
                _seed(st, pp, nodes, seg, plate, tau)
        else:
            tau = _slip(st, pp, nodes, seg, plate, tau)
    raise RuntimeError("planar stick-slip: no progress within a segment")


# --- drivers (:class:`.planar.PlanarStickSlip`) --------------------------------------------------


@_jit
def _through(states: np.ndarray, params: np.ndarray, nodes: np.ndarray, seg: np.ndarray,
             plate: np.ndarray) -> None:  # fmt: skip
    """Every part through ``seg`` (a call of its own: inlined, it slows the held samples' loop ~2×)."""
    for i in range(states.shape[0]):
        run_segment(states[i], params[i], nodes, seg, plate)


@_jit
def run_segments(states: np.ndarray, params: np.ndarray, nodes: np.ndarray, segs: np.ndarray,
                 plate: np.ndarray, every: int, out: np.ndarray) -> None:  # fmt: skip
    """Segments (n, SEG_SIZE) for every part; plate-frame poses every ``every`` segments into ``out``."""
    j = 0
    for k in range(segs.shape[0]):
        seg = segs[k]
        _through(states, params, nodes, seg, plate)
        finish_segment(seg, plate)
        if (k + 1) % every == 0:
            for i in range(states.shape[0]):
                out[i, j, 0], out[i, j, 1], out[i, j, 2] = plate_frame_pose(
                    states[i], plate[0], plate[1], plate[2]
                )
            j += 1


@_jit_inline
def _surely_held(states: np.ndarray, params: np.ndarray, seg: np.ndarray, spin_end: float) -> bool:
    """No stuck part can break loose in the sample ``seg`` (the plate's spin at its end
    ``spin_end``; :meth:`.planar.PlanarStickSlip._surely_held`)."""
    a_lin = math.sqrt(seg[A] * seg[A] + seg[A + 1] * seg[A + 1])
    alpha = abs(seg[A + 2])
    spin2 = max(seg[V + 2] ** 2, spin_end**2)
    for i in range(states.shape[0]):  # rows indexed in place, not viewed
        if states[i, STUCK] == 0:
            return False
        r = math.sqrt(states[i, POSE] ** 2 + states[i, POSE + 1] ** 2)
        measure = params[i, HOLD_F] * (a_lin + alpha * r + spin2 * r) + params[i, HOLD_M] * alpha
        if not measure <= _HELD_MARGIN:
            return False
    return True


@_jit
def run_sampled(states: np.ndarray, params: np.ndarray, nodes: np.ndarray, velocity: np.ndarray,
                rate: float, plate: np.ndarray, skip: bool, out: np.ndarray) -> None:  # fmt: skip
    """Plate velocity samples (3, n), acceleration held between them, for every part; lab poses
    (parts, n, 3) into ``out`` (:meth:`.planar.PlanarStickSlip.advance_sampled`).

    A sample where every part is surely held moves the plate only.  (The loop's body is written
    out: as an inlined function, numba compiles it ~2× slower.)
    """
    seg = np.zeros(SEG_SIZE)
    seg[DURATION] = 1.0 / rate
    for k in range(velocity.shape[1]):
        vx, vy, om = velocity[0, k], velocity[1, k], velocity[2, k]
        seg[V], seg[V + 1], seg[V + 2] = plate[3], plate[4], plate[5]
        seg[A], seg[A + 1], seg[A + 2] = ((vx - plate[3]) * rate, (vy - plate[4]) * rate,
                                          (om - plate[5]) * rate)  # fmt: skip
        if not (skip and _surely_held(states, params, seg, om)):
            _through(states, params, nodes, seg, plate)
        finish_segment(seg, plate)
        # the sample itself, not v₀ + a·dt (which rounds differently): no corner at the next one
        plate[3], plate[4], plate[5] = vx, vy, om
        for i in range(states.shape[0]):
            out[i, k, 0], out[i, k, 1], out[i, k, 2] = _lab_pose_of(states, i, plate[0], plate[1], plate[2])


@_jit_inline
def _drive_state(row: np.ndarray) -> DriveState:
    """A channel's output voltage and filter states from its drive row."""
    z = DRIVE_STATES
    return row[DRIVE_VOLTS], row[z], row[z + 1], row[z + 2], row[z + 3], row[z + 4], row[z + 5]


@_jit_inline
def _keep_drive_state(row: np.ndarray, state: DriveState) -> None:
    z = DRIVE_STATES
    row[DRIVE_VOLTS], row[z], row[z + 1], row[z + 2], row[z + 3], row[z + 4], row[z + 5] = state


@_jit
def run_plant(command: np.ndarray, drive: np.ndarray, states: np.ndarray, params: np.ndarray,
              nodes: np.ndarray, rate: float, plate: np.ndarray, skip: bool,
              out: np.ndarray) -> None:  # fmt: skip
    """:meth:`.planar_plant.PlanarPlant.advance`: the three channels' output stages and stack
    filters (:func:`.kernels.drive_sample`), then :func:`run_sampled`.

    drive (3, DRIVE_SIZE): per channel (x, y, θ) the coefficients and filter states
    (:data:`.kernels.DRIVE_STATES`), the output voltage and the scale from stack velocity to plate
    velocity (one array: one argument to hand over per call, not four); states and voltages updated.
    """
    velocity = np.empty(command.shape)
    for c in range(3):
        row = drive[c]
        state, scale = _drive_state(row), row[DRIVE_SCALE]
        for k in range(command.shape[1]):
            _, v, state = drive_sample(row, command[c, k], state)
            velocity[c, k] = v * scale
        _keep_drive_state(row, state)
    run_sampled(states, params, nodes, velocity, rate, plate, skip, out)
