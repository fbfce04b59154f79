"""Rigid part on the moving plate: exact event-driven stick-slip (DESIGN §4, paper §V.B).

The part sticks while ``|a_plate| ≤ a_s`` (a_s = F_s/m = τ·A_r/m); otherwise it
slips and kinetic friction ``a_k = r·a_s`` (r = F_k/F_s, default 0.8) acts
against the relative velocity; it re-sticks when the relative velocity crosses
zero and ``|a_plate| ≤ a_s``.

Plate motion is given as intervals, each with a duration, a constant plate
acceleration and a plate-velocity jump at its start (the corners of an ideal
sawtooth are jumps: infinite acceleration, the part cannot follow).  On such a
plate the motion is solved exactly: with w = v_part − v_plate and
s = x_part − x_plate, a slipping part has dw/dt = −sign(w)·a_k − a_plate, so w
is linear and s quadratic inside an interval and every zero crossing of w is
found in closed form.  Nothing is stepped with a fixed dt.

Two drivers of the same closed forms (tests check they agree to rounding):

- :class:`StickSlip` streams long sampled series (the plant at 100 kS/s):
  stick spans are skipped in bulk, slip episodes are summed in bulk up to the
  interval where w crosses zero (vectorised over time); that interval and
  the velocity jumps are done in scalar arithmetic.
- :func:`simulate_batch` runs many parameter sets at once (vectorised over the
  sets) through :func:`advance_interval`, interval by interval: the mode for sweeps.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from feeder.errors import InputError
from feeder.plant import kernels

DEFAULT_KINETIC_RATIO = 0.8
KINETIC_RATIO_SPREAD = 0.1
"""Assumed ± spread of F_k/F_s for the step band (not measured in the paper)."""


def kinetic_ratio_band(kinetic_ratio: float) -> tuple[float, float]:
    """F_k/F_s ± :data:`KINETIC_RATIO_SPREAD`, kept inside (0, 1]: (0.7, 0.9) for 0.8."""
    return (max(0.05, kinetic_ratio - KINETIC_RATIO_SPREAD),
            min(1.0, kinetic_ratio + KINETIC_RATIO_SPREAD))  # fmt: skip


_WINDOW = 1024
_MIN_SLIP_WINDOW = 32
_SCALAR = 4


@dataclass(frozen=True)
class Friction:
    """Friction of the part on the plate as accelerations (m/s²).

    static_accel_m_s2: a_s = F_s/m, the plate acceleration the part can follow.
    kinetic_ratio: F_k/F_s in (0, 1].
    """

    static_accel_m_s2: float
    kinetic_ratio: float = DEFAULT_KINETIC_RATIO

    def __post_init__(self) -> None:
        if not (math.isfinite(self.static_accel_m_s2) and self.static_accel_m_s2 > 0):
            raise InputError(
                "static_accel_m_s2", f"must be a positive number, got {self.static_accel_m_s2!r}"
            )
        if not (0 < self.kinetic_ratio <= 1):
            raise InputError("kinetic_ratio", f"must lie in (0, 1], got {self.kinetic_ratio!r}")

    @property
    def kinetic_accel_m_s2(self) -> float:
        return self.kinetic_ratio * self.static_accel_m_s2


def advance_interval(
    stuck: np.ndarray,
    w: np.ndarray,
    s: np.ndarray,
    accel: np.ndarray,
    dt: np.ndarray,
    jump: np.ndarray,
    a_s: np.ndarray,
    a_k: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One interval of constant plate acceleration, exactly, for arrays of parameter sets.

    stuck: part sticks at the interval start; w: relative velocity (m/s);
    s: relative position (m); accel: plate acceleration (m/s²); dt: duration (s);
    jump: plate-velocity jump at the start (m/s); a_s, a_k: static and kinetic
    friction accelerations.  Returns (stuck, w, s, slip_time_s) at the end.
    """
    w = np.where(stuck, 0.0, w) - jump
    big = np.abs(accel) > a_s
    slipping = ~stuck | (jump != 0) | big
    slipping &= ~((w == 0) & ~big)  # at rest relative to a plate it can follow: sticks
    sigma = np.where(w != 0, np.sign(w), -np.sign(accel))
    rate = -sigma * a_k - accel  # dw/dt while slipping with sign sigma
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.where(sigma * rate < 0, -w / rate, np.inf)
    cross = slipping & (tau <= dt)
    tau = np.minimum(tau, dt)
    sticks = cross & ~big
    rate2 = sigma * a_k - accel  # after a crossing with |a| > a_s: slips the other way
    rest = dt - tau
    s_new = np.where(
        cross,
        s + 0.5 * w * tau + np.where(sticks, 0.0, 0.5 * rate2 * rest * rest),
        s + w * dt + 0.5 * rate * dt * dt,
    )
    w_new = np.where(cross, np.where(sticks, 0.0, rate2 * rest), w + rate * dt)
    slip_time = np.where(slipping, np.where(sticks, tau, dt), 0.0)
    return (
        ~slipping | sticks,
        np.where(slipping, w_new, 0.0),
        np.where(slipping, s_new, s),
        slip_time,
    )


MAX_SCATTER = 0.5
"""The largest relative scatter of a_s (1σ): beyond it the clip at 5 % of nominal shapes the draws
(a scatter of 5, meant as 5 %, drove a forward waveform's part backwards by 33 µm a period)."""


class StickSlip:
    """Streaming exact stick-slip of one part, state kept across calls.

    ``scatter`` (0 … :data:`MAX_SCATTER`) > 0 redraws a_s at every re-stick as
    a_s·(1 + scatter·N(0, 1)) (clipped at 5 % of nominal) from a generator seeded with
    ``seed``: the step-to-step spread of a real contact.  a_k follows as r·a_s.
    """

    def __init__(self, friction: Friction, scatter: float = 0.0, seed: int | None = None) -> None:
        if not 0 <= scatter <= MAX_SCATTER:
            raise InputError("scatter", f"must lie in [0, {MAX_SCATTER:g}] (0.05 is 5 %), got {scatter!r}")
        self.friction = friction
        self.scatter = scatter
        self._rng = np.random.default_rng(seed)
        self.stuck = True
        self.relative_velocity_m_s = 0.0
        self.relative_position_m = 0.0
        self.slip_time_s = 0.0
        self.elapsed_s = 0.0
        self.static_accel_m_s2 = friction.static_accel_m_s2
        self._slip_window = _WINDOW
        self._normals = np.zeros(0)  # draws of the generator, used in order by both paths
        self._next_normal = 0
        self._draw()

    def _normal(self) -> float:
        if self._next_normal >= self._normals.size:
            self._refill()
        self._next_normal += 1
        return float(self._normals[self._next_normal - 1])

    def _refill(self) -> None:
        self._normals = np.concatenate([self._normals[self._next_normal :],
                                        kernels.normals_buffer(self._rng)])  # fmt: skip
        self._next_normal = 0

    def _draw(self) -> None:
        nominal = self.friction.static_accel_m_s2
        if self.scatter > 0:
            factor = max(0.05, 1.0 + self.scatter * self._normal())
            self.static_accel_m_s2 = nominal * factor

    @property
    def normals(self) -> np.ndarray:
        """The scatter draws from the next unused one's buffer (kernel state ``NORMAL`` indexes it)."""
        return self._normals

    def state(self) -> np.ndarray:
        """The state as the compiled kernels take it (:mod:`feeder.plant.kernels`)."""
        return np.array([1.0 if self.stuck else 0.0, self.relative_velocity_m_s, self.relative_position_m,
                         self.slip_time_s, self.static_accel_m_s2, self._next_normal])  # fmt: skip

    def set_state(self, st: np.ndarray) -> None:
        """Take the state back from a kernel."""
        (
            stuck,
            self.relative_velocity_m_s,
            self.relative_position_m,
            self.slip_time_s,
            self.static_accel_m_s2,
            normal,
        ) = st.tolist()
        self.stuck = stuck != 0.0
        self._next_normal = int(normal)

    def run_kernel(self, run: Callable[[np.ndarray, int], int], n: int) -> None:
        """Call ``run(state, start)`` until it has done ``n`` intervals, refilling the draws."""
        st = self.state()
        start = 0
        while True:
            start = run(st, start)
            self.set_state(st)
            if start >= n:
                return
            self._refill()
            st[kernels.NORMAL] = 0

    def advance(
        self, accel: np.ndarray, dt: np.ndarray | float, jump: np.ndarray | None = None
    ) -> np.ndarray:
        """Run intervals of constant plate acceleration; returns s = x_part − x_plate at their ends.

        accel: plate acceleration per interval (m/s²); dt: durations (s), one
        value or one per interval; jump: plate-velocity jump at each interval's
        start (m/s), or ``None``.
        """
        a = np.asarray(accel, dtype=float)
        n = a.size
        if np.ndim(dt) == 0:
            dts = np.full(n, float(dt))
            self.elapsed_s += n * float(dt)
        else:
            dts = np.asarray(dt, dtype=float)
            self.elapsed_s += float(dts.sum())
        if kernels.enabled():
            return self._advance_compiled(a, dts, jump)
        jumps = np.zeros(0) if jump is None else np.asarray(jump, dtype=float)
        where = np.flatnonzero(jumps)
        # jumps as Python numbers: this loop runs per jump, where numpy scalars cost ~5×
        jump_at, jump_size, jump_accel = where.tolist(), jumps[where].tolist(), a[where].tolist()
        out = np.empty(n)
        i = 0
        k = 0  # next jump
        while i < n:
            if k < len(jump_at) and jump_at[k] == i:
                self._jump(jump_size[k], jump_accel[k])
                k += 1
            end = jump_at[k] if k < len(jump_at) else n
            if self.stuck:
                i = self._stick_span(i, end, a, out) if i < end else i
            else:
                i = self._slip_span(i, end, a, dts, out)
        return out

    def _advance_compiled(self, a: np.ndarray, dts: np.ndarray, jump: np.ndarray | None) -> np.ndarray:
        jumps = np.zeros(a.size) if jump is None else np.asarray(jump, dtype=float)
        out = np.empty(a.size)
        friction = self.friction
        self.run_kernel(lambda st, start: kernels.stick_slip_run(
            st, a, dts, jumps, friction.static_accel_m_s2, friction.kinetic_ratio, self.scatter,
            self.normals, out, start), a.size)  # fmt: skip
        return out

    def _jump(self, jump: float, accel: float) -> None:
        """A plate-velocity jump (infinite acceleration): the part cannot follow it."""
        self.relative_velocity_m_s = (0.0 if self.stuck else self.relative_velocity_m_s) - jump
        self.stuck = self.relative_velocity_m_s == 0 and abs(accel) <= self.static_accel_m_s2

    def _stick_span(self, i: int, end: int, a: np.ndarray, out: np.ndarray) -> int:
        """Skip to the first interval in [i, end) whose |a| exceeds a_s; returns its index."""
        start = i
        window = _WINDOW
        while i < end:
            stop = min(end, i + window)
            over = np.flatnonzero(np.abs(a[i:stop]) > self.static_accel_m_s2)
            if over.size:
                i += int(over[0])
                self.stuck = False
                self.relative_velocity_m_s = 0.0
                break
            i = stop
            window *= 2
        out[start:i] = self.relative_position_m
        return i

    def _slip_span(self, i: int, end: int, a: np.ndarray, dts: np.ndarray, out: np.ndarray) -> int:
        """Slip in bulk up to the interval where w reaches zero; that one goes to :meth:`_cross`."""
        window = self._slip_window  # twice the last slip episode's length: usually one window
        a_k = self.friction.kinetic_ratio * self.static_accel_m_s2
        start = i
        while i < end:
            w = self.relative_velocity_m_s
            sigma = math.copysign(1.0, w) if w != 0 else -math.copysign(1.0, a[i])
            if end - i <= _SCALAR:  # a few intervals: plain arithmetic beats array calls
                return self._slip_scalar(i, end, a, dts, sigma, a_k, out)
            stop = min(end, i + window)
            h = dts[i:stop]
            dw = (-sigma * a_k - a[i:stop]) * h
            w_end = np.cumsum(dw)
            w_end += w
            back = w_end <= 0 if sigma > 0 else w_end >= 0  # w has reached zero
            m = int(back.argmax())
            hit = bool(back[m])
            if not hit:
                m = stop - i
            if m:
                # s grows by the mean of w over each interval (w is linear inside)
                ds = (w_end[:m] - 0.5 * dw[:m]) * h[:m]
                s_end = np.cumsum(ds)
                s_end += self.relative_position_m
                out[i : i + m] = s_end
                self.relative_position_m = float(s_end[-1])
                self.relative_velocity_m_s = float(w_end[m - 1])
                self.slip_time_s += float(h[:m].sum())
            i += m
            if hit:
                self._slip_window = max(_MIN_SLIP_WINDOW, 2 * (i + 1 - start))
                self._cross(i, a.item(i), dts.item(i), sigma, a_k, out)
                return i + 1
            window *= 2
        return i

    def _slip_scalar(self, i: int, end: int, a: np.ndarray, dts: np.ndarray, sigma: float,
                     a_k: float, out: np.ndarray) -> int:  # fmt: skip
        """:meth:`_slip_span` for a handful of intervals, one at a time."""
        w, s = self.relative_velocity_m_s, self.relative_position_m
        for k in range(i, end):
            accel, h = a.item(k), dts.item(k)
            w_end = w + (-sigma * a_k - accel) * h
            if (w_end <= 0) if sigma > 0 else (w_end >= 0):
                self.relative_velocity_m_s, self.relative_position_m = w, s
                self._cross(k, accel, h, sigma, a_k, out)
                return k + 1
            s += 0.5 * (w + w_end) * h
            w = w_end
            out[k] = s
            self.slip_time_s += h
        self.relative_velocity_m_s, self.relative_position_m = w, s
        return end

    def _cross(self, i: int, accel: float, dt: float, sigma: float, a_k: float,
               out: np.ndarray) -> None:  # fmt: skip
        """The interval where w reaches zero (the crossing branch of :func:`advance_interval`)."""
        w = self.relative_velocity_m_s
        tau = min(-w / (-sigma * a_k - accel), dt) if w != 0 else 0.0
        s = self.relative_position_m + 0.5 * w * tau
        if abs(accel) <= self.static_accel_m_s2:  # the plate can carry it: sticks
            self.stuck, self.relative_velocity_m_s = True, 0.0
            self.slip_time_s += tau
            self._draw()
        else:  # slips on the other way
            rate = sigma * a_k - accel
            rest = dt - tau
            s += 0.5 * rate * rest * rest
            self.relative_velocity_m_s = rate * rest
            self.slip_time_s += dt
        self.relative_position_m = s
        out[i] = s


def simulate_batch(
    accel: np.ndarray,
    dt: np.ndarray,
    jump: np.ndarray,
    static_accel_m_s2: np.ndarray | float,
    kinetic_ratio: np.ndarray | float = DEFAULT_KINETIC_RATIO,
) -> tuple[np.ndarray, np.ndarray]:
    """Many parameter sets at once, each starting stuck at s = 0.

    accel, dt, jump: arrays (sets, intervals) (broadcast); the friction values
    broadcast over the sets.  Returns (s at each interval end, shape
    (sets, intervals); total slip time per set, s).
    """
    accel, dt, jump = np.broadcast_arrays(np.atleast_2d(accel), np.atleast_2d(dt), np.atleast_2d(jump))
    sets, n = accel.shape
    a_s = np.broadcast_to(np.asarray(static_accel_m_s2, dtype=float), (sets,))
    a_k = np.asarray(kinetic_ratio, dtype=float) * a_s
    stuck = np.ones(sets, dtype=bool)
    w = np.zeros(sets)
    s = np.zeros(sets)
    slip_total = np.zeros(sets)
    out = np.empty((sets, n))
    for k in range(n):
        stuck, w, s, slip = advance_interval(stuck, w, s, accel[:, k], dt[:, k], jump[:, k], a_s, a_k)
        slip_total += slip
        out[:, k] = s
    return out, slip_total
