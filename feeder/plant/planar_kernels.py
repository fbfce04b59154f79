"""Compiled planar stick-slip (numba, extra ``fast``; plain Python without it): :mod:`.planar` on arrays.

The same event-driven solver as :class:`feeder.plant.planar_reference.PartState` (the
reference, run when :func:`feeder.plant.kernels.enabled` is false), in scalar
code over float arrays so that numba compiles a whole segment, a whole
sampled chunk or a whole run: a part's events here (breakaway by Brent's
method, re-stick, slip along a line in closed form), slip episodes in
:mod:`.slip_kernels`, the limit surface in :mod:`.limit_surface_kernels`,
the arrays' layouts in :mod:`.planar_arrays`; the drivers over samples and
segments.  Results agree with the reference to the integrators' tolerance
(tests/test_plant_kernels.py).
"""

from __future__ import annotations

import math

import numpy as np

from feeder.plant.kernels import DriveState, _jit, _jit_inline, contact_interval, drive_sample
from feeder.plant.limit_surface_kernels import gauge, holds
from feeder.plant.planar_arrays import (
    A_S,
    DERIV_AT,
    DRIVE_SCALE,
    DRIVE_STATES,
    DRIVE_VOLTS,
    DURATION,
    ELAPSED,
    HOLD_F,
    HOLD_M,
    INERTIA,
    LAB,
    MASS,
    POSE,
    RADIUS,
    RATIO,
    SEG_SIZE,
    SLIP,
    STEP,
    STOP,
    STUCK,
    TAU_S,
    A,
    V,
    carry,
    finish_segment,
    is_smooth,
    is_turning,
    lab_pose,
    lab_pose_of,
    plate_accel,
    plate_at,
    plate_frame_pose,
    plate_velocity,
    relative_twist,
    twist_dot,
)
from feeder.plant.slip_kernels import _EPS, integrate_slip

_SEED_TIME_S = 1e-12
"""A part breaking loose starts with the twist a_s·1e-12 s along its breakaway direction."""
_STOP = 1e-10
"""A slip ends when the twist has fallen below this fraction of its value at the start."""
_BREAKAWAY_SAMPLES = 16
_HELD_MARGIN = 1 - 1e-6
_NO_DRAWS = np.zeros(0)


@_jit
def _required(st: np.ndarray, pp: np.ndarray, seg: np.ndarray, plate: np.ndarray,
              tau: float) -> tuple[float, float, float]:  # fmt: skip
    """Wrench (F_x, F_y, M) in the part frame that carries the stuck part at τ."""
    px, py, pth = plate_at(seg, plate, tau)
    om = plate_velocity(seg, tau)[2]
    ax, ay, alpha = plate_accel(seg, tau)
    cx, cy, phi = lab_pose(st, px, py, pth)
    rx, ry = cx - px, cy - py
    om2 = om * om
    m = pp[MASS]
    fx, fy = m * (ax - alpha * ry - om2 * rx), m * (ay + alpha * rx - om2 * ry)
    c, s = math.cos(phi), math.sin(phi)
    return c * fx + s * fy, -s * fx + c * fy, pp[INERTIA] * alpha


@_jit
def _seed(st: np.ndarray, pp: np.ndarray, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
          tau: float) -> None:  # fmt: skip
    """Start a slip from (near) zero twist along the breakaway direction of the required wrench."""
    fx, fy, m = _required(st, pp, seg, plate, tau)
    _, wx, wy, om = gauge(pp, st[RADIUS], nodes, fx, fy, m)
    c, s = math.cos(st[LAB + 2]), math.sin(st[LAB + 2])
    lx, ly = c * wx - s * wy, s * wx + c * wy
    size = math.sqrt(twist_dot(pp, lx, ly, om, lx, ly, om))
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
    smooth = is_smooth(seg)
    if smooth and not is_turning(seg):  # constant wrench m·a, a pure force
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


@_jit
def _settle(st: np.ndarray, pp: np.ndarray, nodes: np.ndarray, seg: np.ndarray, plate: np.ndarray,
            tau: float) -> None:  # fmt: skip
    """The twist has vanished at τ: sticks if the static surface holds it, else slips on."""
    px, py, pth = plate_at(seg, plate, tau)
    st[POSE], st[POSE + 1], st[POSE + 2] = plate_frame_pose(st, px, py, pth)
    st[STUCK] = 1.0
    fx, fy, m = _required(st, pp, seg, plate, tau)
    if not holds(pp, st[RADIUS], nodes, fx, fy, m):
        vx, vy, om = plate_velocity(seg, tau)
        carry(st, px, py, pth, vx, vy, om)
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
        px, py, pth = plate_at(seg, plate, tau)
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
    q0x, q0y, _ = plate_at(seg, plate, tau)
    q1x, q1y, q1th = plate_at(seg, plate, seg[DURATION])
    v1x, v1y, _ = plate_velocity(seg, seg[DURATION])
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
    px, py, _ = plate_at(seg, plate, tau)
    vx, vy, om = plate_velocity(seg, tau)
    w0, w1, w2 = relative_twist(st[LAB], st[LAB + 1], st[LAB + 3], st[LAB + 4], st[LAB + 5], px, py,
                                vx, vy, om)  # fmt: skip
    if is_smooth(seg) and not is_turning(seg) and w2 == 0 and w0 * seg[A + 1] == w1 * seg[A]:
        return _slip_straight(st, pp, seg, plate, tau, w0, w1)
    x0, y0, phi0 = st[LAB], st[LAB + 1], st[LAB + 2]
    y = np.array([0.0, 0.0, 0.0, st[LAB + 3], st[LAB + 4], st[LAB + 5]])
    carried = (tau == 0 and st[DERIV_AT] > 0 and st[DERIV_AT] == plate[ELAPSED] and seg[V] == plate[3]
               and seg[V + 1] == plate[4] and seg[V + 2] == plate[5])  # fmt: skip
    st[DERIV_AT] = 0.0
    end, stopped = integrate_slip(st, pp, nodes, seg, plate, x0, y0, phi0, tau, y, carried)
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
        carry(st, px, py, pth, plate[3], plate[4], plate[5])
        st[STUCK] = 0.0
        w0, w1, w2 = relative_twist(st[LAB], st[LAB + 1], st[LAB + 3], st[LAB + 4], st[LAB + 5], px, py,
                                    seg[V], seg[V + 1], seg[V + 2])  # fmt: skip
        st[STOP] = _STOP * math.sqrt(twist_dot(pp, w0, w1, w2, w0, w1, w2))
        st[STEP] = 0.0
    for _ in range(10_000):
        if tau >= seg[DURATION]:
            return
        if st[STUCK] != 0:
            start = _breakaway(st, pp, nodes, seg, plate, tau)
            if start < 0:
                return
            tau = start
            qx, qy, qth = plate_at(seg, plate, tau)
            vx, vy, om = plate_velocity(seg, tau)
            carry(st, qx, qy, qth, vx, vy, om)
            st[STUCK] = 0.0
            st[STEP] = 0.0
            if is_turning(seg) or not is_smooth(seg):  # else the 1-D closed form starts it
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
            out[i, k, 0], out[i, k, 1], out[i, k, 2] = lab_pose_of(states, i, plate[0], plate[1], plate[2])


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
