"""One slip episode of a part on the plate, compiled (numba, extra ``fast``): Dormand-Prince 5(4)
(scipy's RK45 step control; the step size carries over from one segment to the next within an
episode), in time while the twist grows and in ln|twist| (:func:`_fade`) while it fades, the
twist's vanishing by the reference's drop-and-shorten rule (:meth:`.planar_reference.PartState._integrate`).
"""

from __future__ import annotations

import math

import numpy as np

from feeder.plant.kernels import _jit, _jit_inline
from feeder.plant.limit_surface_kernels import integrals
from feeder.plant.planar_arrays import (
    DERIV,
    DERIV_AT,
    DURATION,
    ELAPSED,
    FADE_STEP,
    INERTIA,
    MASS,
    RADIUS,
    RTOL,
    STEP,
    STEPS,
    STOP,
    TAU_K,
    plate_accel,
    plate_at,
    plate_velocity,
    relative_twist,
    twist_dot,
)

_ROUNDING = 1e-14
"""A twist this small relative to the part's lab velocity is rounding: it has vanished."""
_ALIGNED = 0.9
_STRAIGHT = 0.5
"""A twist shrinking this straight (cosine of twist and its rate) fades in ln|twist| (:func:`_fade`)."""
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
_EPS = float(np.finfo(np.float64).eps)


# Dormand-Prince 5(4) (scipy's RK45); no nodes c_i: the time is z's last component
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


@_jit_inline
def _rhs(pp: np.ndarray, radius: float, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
         x0: float, y0: float, phi0: float, t: float, y: np.ndarray, out: np.ndarray) -> None:  # fmt: skip
    """Rigid-body motion under kinetic friction; y = (c − c₀, φ − φ₀, v, ω), lab frame."""
    px, py, _ = plate_at(seg, plate, t)
    vx, vy, om = plate_velocity(seg, t)
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
    px, py, _ = plate_at(seg, plate, t)
    vx, vy, om = plate_velocity(seg, t)
    return relative_twist(x0 + y[0], y0 + y[1], y[3], y[4], y[5], px, py, vx, vy, om)


@_jit_inline
def _twist_rate(seg: np.ndarray, plate: np.ndarray, x0: float, y0: float, t: float, y: np.ndarray,
                f: np.ndarray) -> tuple[float, float, float]:  # fmt: skip
    """d(w, ω_r)/dt = (dv/dt − a_plate(c) − Ω ẑ×w, dω/dt − α), f the state's derivative."""
    px, py, _ = plate_at(seg, plate, t)
    om = plate_velocity(seg, t)[2]
    ax, ay, alpha = plate_accel(seg, t)
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
    shrink = twist_dot(pp, p0, p1, p2, d0, d1, d2)
    size2 = twist_dot(pp, p0, p1, p2, p0, p1, p2)
    if not shrink < -_STRAIGHT * math.sqrt(size2 * twist_dot(pp, d0, d1, d2, d0, d1, d2)):
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
    size = math.sqrt(twist_dot(pp, p0, p1, p2, p0, p1, p2))
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
    return math.sqrt(twist_dot(pp, r0, r1, r2, r0, r1, r2))


@_jit_inline
def _shrinks(seg: np.ndarray, plate: np.ndarray, x0: float, y0: float, pp: np.ndarray, z: np.ndarray,
             f: np.ndarray, w0: float, w1: float, w2: float) -> bool:  # fmt: skip
    """Whether the twist (w) at z, f = dz/dt, shrinks."""
    d0, d1, d2 = _twist_rate(seg, plate, x0, y0, z[6], z, f)
    return twist_dot(pp, w0, w1, w2, d0, d1, d2) < 0


@_jit
def integrate_slip(st: np.ndarray, pp: np.ndarray, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
               x0: float, y0: float, phi0: float, t: float, y: np.ndarray,
               carried: bool) -> tuple[float, bool]:  # fmt: skip
    """From t towards the segment's end until the twist vanishes; y updated, returns (time, vanished).

    In time (scipy's RK45 step control) while the twist grows, as
    :meth:`.planar_reference.PartState._integrate` (a step that reverses the twist is
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
            shrink = twist_dot(pp, p0, p1, p2, d0, d1, d2)
            size2 = twist_dot(pp, p0, p1, p2, p0, p1, p2)
            aligned = shrink < -_ALIGNED * math.sqrt(size2 * twist_dot(pp, d0, d1, d2, d0, d1, d2))
            if fade and aligned and -size2 / shrink < 2 * (t_end - z[6]):  # it vanishes in this segment
                floor = _ROUNDING * math.sqrt(twist_dot(pp, z[3], z[4], z[5], z[3], z[4], z[5]))
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
                rate2 = twist_dot(pp, d0, d1, d2, d0, d1, d2)
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
            if twist_dot(pp, n0, n1, n2, p0, p1, p2) <= 0:
                reversed_ = True
                break
            z[:] = z_new
            ks[0, :] = ks[6]
            p0, p1, p2 = n0, n1, n2
            fade = True
            floor = _ROUNDING * math.sqrt(twist_dot(pp, z[3], z[4], z[5], z[3], z[4], z[5]))
            size = math.sqrt(twist_dot(pp, n0, n1, n2, n0, n1, n2))
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
        size2 = twist_dot(pp, p0, p1, p2, p0, p1, p2)
        rate2 = twist_dot(pp, d0, d1, d2, d0, d1, d2)
        along = twist_dot(pp, p0, p1, p2, d0, d1, d2)
        to_zero = -along / rate2 if rate2 > 0 else 0.0
        if not to_zero > 0 or size2 - along * along / rate2 >= _MISS2 * size2:
            # the twist turns rather than vanishes (a near miss): on in time, steps within its turn
            floor = _ROUNDING * math.sqrt(twist_dot(pp, z[3], z[4], z[5], z[3], z[4], z[5]))
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
