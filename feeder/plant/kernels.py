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
DriveState = tuple[float, float, float, float, float, float, float]
DRIVE_STATES = 19
"""Columns of a channel's drive row: 0–18 the coefficients (v_min, v_max, max step per sample
(V), then the stack filter's position row b[0:4], a[0:4] and velocity row b[0:4], a[0:4], a[0] = 1;
direct form II transposed, as scipy's lfilter), then the two rows' states (3 + 3)."""


@_jit_inline
def drive_sample(cf: np.ndarray, command: float, state: DriveState) -> tuple[float, float, DriveState]:
    """One sample of an output stage and stack filter (coefficients ``cf``, :data:`DRIVE_STATES`):
    the command (V) through the rails and the slope limit from the output voltage, then the
    filter; returns (stack position, stack velocity, the new state).  state: (output voltage,
    the position row's 3 filter states, the velocity row's 3)."""
    y, p0, p1, p2, q0, q1, q2 = state
    u = min(max(command, cf[0]), cf[1])
    y = min(max(u, y - cf[2]), y + cf[2])  # rails, then the slope limit
    x = cf[3] * y + p0
    p0 = cf[4] * y + p1 - cf[8] * x
    p1 = cf[5] * y + p2 - cf[9] * x
    p2 = cf[6] * y - cf[10] * x
    v = cf[11] * y + q0
    q0 = cf[12] * y + q1 - cf[16] * v
    q1 = cf[13] * y + q2 - cf[17] * v
    q2 = cf[14] * y - cf[18] * v
    return x, v, (y, p0, p1, p2, q0, q1, q2)


@_jit
def plant_run(command: np.ndarray, coef: np.ndarray, z: np.ndarray, plate: np.ndarray,
              st: np.ndarray, nominal: float, ratio: float, scatter: float, normals: np.ndarray,
              part_out: np.ndarray, plate_out: np.ndarray, start: int) -> int:  # fmt: skip
    """Samples ``start``… of :meth:`.plant.Plant.advance_traces`, one at a time.

    coef: the channel's coefficients (:data:`DRIVE_STATES`); z: the stack
    filter's two rows' states (3 + 3, updated); plate: (output voltage, plate
    velocity before, sample rate), updated.  Returns the index reached (see
    :func:`stick_slip_run`).
    """
    n = command.size
    drive = (plate[0], z[0], z[1], z[2], z[3], z[4], z[5])
    v_prev, rate = plate[1], plate[2]
    h = 1.0 / rate
    stuck, w, s, slip, a_s, k = st[STUCK] != 0.0, st[W], st[S], st[SLIP], st[A_S], int(st[NORMAL])
    i = start
    while i < n:
        if scatter > 0.0 and k >= normals.size:
            break
        x, v, drive = drive_sample(coef, command[i], drive)
        stuck, w, s, slip, a_s, k = contact_interval(stuck, w, s, slip, a_s, k, (v - v_prev) * rate, h, 0.0,
                                             nominal, ratio, scatter, normals)  # fmt: skip
        part_out[i] = x + s
        plate_out[i] = x
        v_prev = v
        i += 1
    plate[0], z[0], z[1], z[2], z[3], z[4], z[5] = drive
    plate[1] = v_prev
    st[STUCK], st[W], st[S], st[SLIP], st[A_S], st[NORMAL] = 1.0 if stuck else 0.0, w, s, slip, a_s, k
    return i


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
