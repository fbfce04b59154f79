"""Compiled inner loops of the streaming plant (numba, optional; extra ``fast``).

The numpy code in :mod:`.stick_slip`, :mod:`.amplifier` and :mod:`.stack` is
the reference and the fallback.  The limit-surface integrals of a rectangle
(:func:`rectangle_integrals`, the planar solver's inner loop) are scalar code
that runs compiled, or as plain Python without numba.  These kernels run the same closed forms one
sample at a time in scalar arithmetic, compiled with numba when it is
installed: at 1 ms chunks (100 samples) the numpy path costs mostly per-call
overhead, the kernels none.  Results agree with the numpy path to rounding
(tests run both).  ``FEEDER_NUMBA=0`` in the environment, or
:func:`use_compiled` ``(False)``, selects the numpy path.

Contact state (float64 array, :data:`STATE_SIZE`): stuck (0/1), relative
velocity w (m/s), relative position s (m), slip time (s), current a_s (m/s²),
index of the next standard normal in the scatter buffer.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from typing import Any

import numpy as np

try:
    import numba
except ImportError:  # the optional extra ``fast`` is not installed: numpy only
    numba = None  # type: ignore[assignment]

STATE_SIZE = 6
STUCK, W, S, SLIP, A_S, NORMAL = range(STATE_SIZE)

AVAILABLE = numba is not None
_enabled = AVAILABLE and os.environ.get("FEEDER_NUMBA", "1") != "0"


def enabled() -> bool:
    """True if the streaming plant uses the compiled kernels."""
    return _enabled


def use_compiled(flag: bool) -> None:
    """Switch the kernels on (needs numba) or off (numpy path), e.g. to compare the two."""
    global _enabled
    _enabled = bool(flag) and AVAILABLE


def _jit(func: Callable[..., Any]) -> Callable[..., Any]:
    return numba.njit(cache=True, nogil=True)(func) if AVAILABLE else func


def _jit_inline(func: Callable[..., Any]) -> Callable[..., Any]:
    """:func:`_jit`, inlined into its callers by numba (no call, no reference counts of the arrays
    handed over: small functions called per limit-surface evaluation)."""
    return numba.njit(cache=True, nogil=True, inline="always")(func) if AVAILABLE else func


@_jit
def contact_interval(stuck: bool, w: float, s: float, slip: float, a_s: float, k: int, acc: float, h: float,
             jump: float, nominal: float, ratio: float, scatter: float,
             normals: np.ndarray) -> tuple[bool, float, float, float, float, int]:  # fmt: skip
    """One interval of constant plate acceleration (:func:`.stick_slip.advance_interval`).

    Takes and returns (stuck, w, s, slip time, a_s, next normal).
    """
    if jump != 0.0:  # the part cannot follow a velocity jump
        w = (0.0 if stuck else w) - jump
        stuck = w == 0.0 and abs(acc) <= a_s
    if stuck and abs(acc) > a_s:  # breaks loose
        stuck = False
        w = 0.0
    if not stuck:
        a_k = ratio * a_s
        sigma = math.copysign(1.0, w) if w != 0.0 else -math.copysign(1.0, acc)
        rate = -sigma * a_k - acc
        w_end = w + rate * h
        if (w_end <= 0.0) if sigma > 0 else (w_end >= 0.0):  # w reaches zero in the interval
            tau = min(-w / rate, h) if w != 0.0 else 0.0
            s += 0.5 * w * tau
            if abs(acc) <= a_s:  # the plate can carry it: sticks
                stuck = True
                w = 0.0
                slip += tau
                if scatter > 0.0:
                    a_s = nominal * max(0.05, 1.0 + scatter * normals[k])
                    k += 1
            else:  # slips on the other way
                rate2 = sigma * a_k - acc
                rest = h - tau
                s += 0.5 * rate2 * rest * rest
                w = rate2 * rest
                slip += h
        else:
            s += 0.5 * (w + w_end) * h
            w = w_end
            slip += h
    return stuck, w, s, slip, a_s, k


@_jit
def stick_slip_run(st: np.ndarray, accel: np.ndarray, dts: np.ndarray, jumps: np.ndarray,
                   nominal: float, ratio: float, scatter: float, normals: np.ndarray,
                   out: np.ndarray, start: int) -> int:  # fmt: skip
    """Intervals ``start``… of :meth:`.stick_slip.StickSlip.advance`; s at each end into ``out``.

    Returns the index reached: ``accel.size``, or earlier when a re-stick
    would need a scatter draw beyond ``normals`` (refill and call again).
    """
    n = accel.size
    stuck, w, s, slip, a_s, k = st[STUCK] != 0.0, st[W], st[S], st[SLIP], st[A_S], int(st[NORMAL])
    i = start
    while i < n:
        if scatter > 0.0 and k >= normals.size:
            break
        stuck, w, s, slip, a_s, k = contact_interval(stuck, w, s, slip, a_s, k, accel[i], dts[i], jumps[i],
                                             nominal, ratio, scatter, normals)  # fmt: skip
        out[i] = s
        i += 1
    st[STUCK], st[W], st[S], st[SLIP], st[A_S], st[NORMAL] = 1.0 if stuck else 0.0, w, s, slip, a_s, k
    return i


FILTER_ORDER = 3
"""The compiled plant's stack filters are third order (rows padded to 4 coefficients)."""


@_jit
def plant_run(command: np.ndarray, coef: np.ndarray, z: np.ndarray, plate: np.ndarray,
              st: np.ndarray, nominal: float, ratio: float, scatter: float, normals: np.ndarray,
              part_out: np.ndarray, plate_out: np.ndarray, start: int) -> int:  # fmt: skip
    """Samples ``start``… of :meth:`.plant.Plant.advance_traces`, one at a time.

    coef: v_min, v_max, max step per sample (V), then the position row b[0:4],
    a[0:4] and the velocity row b[0:4], a[0:4] of the stack filter (a[0] = 1;
    direct form II transposed, as scipy's lfilter); z: the two rows' states
    (3 + 3, updated); plate: (output voltage, plate velocity before, sample
    rate), updated.  Returns the index reached (see :func:`stick_slip_run`).
    """
    n = command.size
    lo, hi, d = coef[0], coef[1], coef[2]
    pb0, pb1, pb2, pb3, pa1, pa2, pa3 = coef[3], coef[4], coef[5], coef[6], coef[8], coef[9], coef[10]
    vb0, vb1, vb2, vb3, va1, va2, va3 = coef[11], coef[12], coef[13], coef[14], coef[16], coef[17], coef[18]
    p0, p1, p2, q0, q1, q2 = z[0], z[1], z[2], z[3], z[4], z[5]
    y, v_prev, rate = plate[0], plate[1], plate[2]
    h = 1.0 / rate
    stuck, w, s, slip, a_s, k = st[STUCK] != 0.0, st[W], st[S], st[SLIP], st[A_S], int(st[NORMAL])
    i = start
    while i < n:
        if scatter > 0.0 and k >= normals.size:
            break
        u = min(max(command[i], lo), hi)
        y = min(max(u, y - d), y + d)  # rails, then the slope limit
        x = pb0 * y + p0
        p0 = pb1 * y + p1 - pa1 * x
        p1 = pb2 * y + p2 - pa2 * x
        p2 = pb3 * y - pa3 * x
        v = vb0 * y + q0
        q0 = vb1 * y + q1 - va1 * v
        q1 = vb2 * y + q2 - va2 * v
        q2 = vb3 * y - va3 * v
        stuck, w, s, slip, a_s, k = contact_interval(stuck, w, s, slip, a_s, k, (v - v_prev) * rate, h, 0.0,
                                             nominal, ratio, scatter, normals)  # fmt: skip
        part_out[i] = x + s
        plate_out[i] = x
        v_prev = v
        i += 1
    z[0], z[1], z[2], z[3], z[4], z[5] = p0, p1, p2, q0, q1, q2
    plate[0], plate[1] = y, v_prev
    st[STUCK], st[W], st[S], st[SLIP], st[A_S], st[NORMAL] = 1.0 if stuck else 0.0, w, s, slip, a_s, k
    return i


@_jit
def drive_run(command: np.ndarray, coef: np.ndarray, z: np.ndarray, volts: np.ndarray, scale: np.ndarray,
              velocity: np.ndarray) -> None:  # fmt: skip
    """Several channels' output stage and stack filter (as :func:`plant_run`, no contact), sample by sample.

    command (channels, n) in V; coef, z: per channel as :func:`plant_run`
    (rows); volts: each output's voltage, updated; scale: each channel's
    factor from stack velocity to plate velocity; velocity (channels, n) out.
    """
    for c in range(command.shape[0]):
        cf, zc = coef[c], z[c]
        lo, hi, d = cf[0], cf[1], cf[2]
        pb0, pb1, pb2, pb3, pa1, pa2, pa3 = cf[3], cf[4], cf[5], cf[6], cf[8], cf[9], cf[10]
        vb0, vb1, vb2, vb3, va1, va2, va3 = cf[11], cf[12], cf[13], cf[14], cf[16], cf[17], cf[18]
        p0, p1, p2, q0, q1, q2 = zc[0], zc[1], zc[2], zc[3], zc[4], zc[5]
        y, k = volts[c], scale[c]
        for i in range(command.shape[1]):
            u = min(max(command[c, i], lo), hi)
            y = min(max(u, y - d), y + d)  # rails, then the slope limit
            x = pb0 * y + p0
            p0 = pb1 * y + p1 - pa1 * x
            p1 = pb2 * y + p2 - pa2 * x
            p2 = pb3 * y - pa3 * x
            v = vb0 * y + q0
            q0 = vb1 * y + q1 - va1 * v
            q1 = vb2 * y + q2 - va2 * v
            q2 = vb3 * y - va3 * v
            velocity[c, i] = v * k
        zc[0], zc[1], zc[2], zc[3], zc[4], zc[5] = p0, p1, p2, q0, q1, q2
        volts[c] = y


@_jit
def _asinh_ratio(y: float, x: float, r: float) -> float:
    """asinh(y/|x|) for x ≠ 0, r = √(x² + y²): log1p of an exact small argument (no cancellation)."""
    ax = abs(x)
    return math.copysign(math.log1p((abs(y) + y * y / (r + ax)) / ax), y)


@_jit
def _corners(x: float, y: float) -> tuple[float, float, float]:
    """Corner functions of ∫∫ x/r, ∫∫ y/r and ∫∫ r dx dy at (x, y), sharing r and the two logarithms."""
    r = math.sqrt(x * x + y * y)  # no over- or underflow at a part's size (m)
    lx = _asinh_ratio(y, x, r) if x else 0.0
    ly = _asinh_ratio(x, y, r) if y else 0.0
    return (
        0.5 * (y * r + x * x * lx),
        0.5 * (x * r + y * y * ly),
        x * y * r / 3.0 + (x**3 * lx + y**3 * ly) / 6.0,
    )


@_jit
def box_r(x1: float, x2: float, y1: float, y2: float) -> float:
    """∫∫ r over [x1, x2] × [y1, y2]."""
    return _corners(x2, y2)[2] - _corners(x1, y2)[2] - _corners(x2, y1)[2] + _corners(x1, y1)[2]


@_jit
def _asinh_difference(u1: float, u2: float, c: float, r1: float, r2: float) -> float:
    """asinh(u2/|c|) − asinh(u1/|c|) for u1 < u2, r = √(c² + u²): one logarithm of the ratio
    (u2 + r2)/(u1 + r1), without cancellation (log1p of the exact excess when both u ≥ 0)."""
    if c == 0:
        return 0.0  # multiplied by c² (the corner functions' x² lx, x³ lx)
    if u2 <= 0:  # both ≤ 0: the same difference mirrored
        u1, u2, r1, r2 = -u2, -u1, r2, r1
    if u1 >= 0:
        return math.log1p((u2 - u1) * (1 + (u2 + u1) / (r1 + r2)) / (u1 + r1))
    ac = abs(c)
    return math.log((u2 + r2) / ac) + math.log((r1 - u1) / ac)  # u1 + r1 = c²/(r1 − u1)


@_jit
def rectangle_integrals(wx: float, wy: float, omega: float, a: float,
                        b: float) -> tuple[float, float, float, float]:  # fmt: skip
    """:meth:`feeder.plant.limit_surface.Patch.integrals` of the rectangle [−a, a] × [−b, b], ω ≠ 0.

    In closed form about the instantaneous centre of rotation ρ_c = ẑ×w/ω
    (corner functions of ∫∫x/r, ∫∫y/r and ∫∫r at the four corners, :func:`_corners`); the
    logarithms of corners on a common edge line enter as one difference
    (:func:`_asinh_difference`): 4 logarithms, not 8.
    """
    xc, yc = -wy / omega, wx / omega
    x1, x2, y1, y2 = -a - xc, a - xc, -b - yc, b - yc
    r11, r12 = math.sqrt(x1 * x1 + y1 * y1), math.sqrt(x1 * x1 + y2 * y2)
    r21, r22 = math.sqrt(x2 * x2 + y1 * y1), math.sqrt(x2 * x2 + y2 * y2)
    ex1, ex2 = _asinh_difference(y1, y2, x1, r11, r12), _asinh_difference(y1, y2, x2, r21, r22)
    ey1, ey2 = _asinh_difference(x1, x2, y1, r11, r21), _asinh_difference(x1, x2, y2, r12, r22)
    ix = 0.5 * (y2 * (r22 - r12) - y1 * (r21 - r11) + x2 * x2 * ex2 - x1 * x1 * ex1)
    iy = 0.5 * (x2 * (r22 - r21) - x1 * (r12 - r11) + y2 * y2 * ey2 - y1 * y1 * ey1)
    ir = ((x2 * y2 * r22 - x1 * y2 * r12 - x2 * y1 * r21 + x1 * y1 * r11) / 3.0
          + (x2**3 * ex2 - x1**3 * ex1 + y2**3 * ey2 - y1**3 * ey1) / 6.0)  # fmt: skip
    sign = math.copysign(1.0, omega)
    return -sign * iy, sign * ix, sign * (ir + xc * ix + yc * iy), abs(omega) * ir


def normals_buffer(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """The next ``size`` standard normals of ``rng`` (the same sequence as single draws)."""
    return rng.standard_normal(size)
