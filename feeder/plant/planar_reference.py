"""The reference solver of one part's planar stick-slip (:mod:`.planar`), in scipy: slip episodes by
DOP853 (rtol 1e-10) to the time the twist vanishes, breakaway by Brent's method on the limit
surface's gauge (:meth:`.limit_surface.Patch.gauge`), a slip along a fixed line in the 1-D closed
form.  The compiled kernels (:mod:`.planar_kernels`) are checked against it
(tests/test_plant_kernels.py); it runs when they are not enabled.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.integrate import DOP853
from scipy.optimize import brentq

from feeder.plant import kernels
from feeder.plant.planar_kernels import _BREAKAWAY_SAMPLES, _NO_DRAWS, _SEED_TIME_S, _STOP
from feeder.plant.planar_part import PlanarPart, Pose
from feeder.plant.plate_motion import Segment
from feeder.plant.slip_kernels import _MISS2, _NEAR_ZERO, _ROUNDING, _UNRESOLVED

_ATOL = np.array([1e-16, 1e-16, 1e-13, 1e-13, 1e-13, 1e-9])
"""Absolute tolerances of (c − c₀, φ − φ₀, v, ω) at :data:`RTOL` (scaled with rtol)."""
RTOL = 1e-10
"""Relative tolerance of the slip episodes' integration (:func:`simulate`)."""


class Plate:
    """The plate's pose (x_O, y_O, θ) at the start of the current segment, and its velocity."""

    def __init__(self, velocity: tuple[float, float, float]) -> None:
        self.pose = (0.0, 0.0, 0.0)
        self.velocity = velocity

    def at(self, seg: Segment, tau: float) -> tuple[Pose, tuple[float, float, float]]:
        d = seg.position(tau)
        return (self.pose[0] + d[0], self.pose[1] + d[1], self.pose[2] + d[2]), seg.velocity_at(tau)

    def finish(self, seg: Segment) -> None:
        self.pose, self.velocity = self.at(seg, seg.duration_s)


class PartState:
    """One part's running state: stuck (plate-frame pose) or slipping (lab-frame rigid body)."""

    def __init__(self, part: PlanarPart, rtol: float) -> None:
        self.part = part
        self._rtol = rtol
        self.stuck = True
        self.pose = part.pose
        self.lab = [0.0] * 6  # c_x, c_y, φ, v_x, v_y, ω while slipping
        self.slip_time_s = 0.0
        self._stop = 0.0
        self._tau_s = part.static_stress_pa
        self._tau_k = part.friction.kinetic_ratio * self._tau_s

    # --- kinematics -------------------------------------------------------
    def plate_pose(self, plate: Pose) -> Pose:
        """This part's pose in the plate frame, the plate at ``plate``."""
        if self.stuck:
            return self.pose
        c, s = math.cos(plate[2]), math.sin(plate[2])
        dx, dy = self.lab[0] - plate[0], self.lab[1] - plate[1]
        return c * dx + s * dy, -s * dx + c * dy, self.lab[2] - plate[2]

    def lab_pose(self, plate: Pose) -> Pose:
        if not self.stuck:
            return self.lab[0], self.lab[1], self.lab[2]
        c, s = math.cos(plate[2]), math.sin(plate[2])
        x, y, psi = self.pose
        return plate[0] + c * x - s * y, plate[1] + s * x + c * y, plate[2] + psi

    def _carried(self, plate: Pose, velocity: tuple[float, float, float]) -> list[float]:
        """Lab state of the part moving rigidly with the plate."""
        cx, cy, phi = self.lab_pose(plate)
        rx, ry = cx - plate[0], cy - plate[1]
        om = velocity[2]
        return [cx, cy, phi, velocity[0] - om * ry, velocity[1] + om * rx, om]

    def _required(self, seg: Segment, plate: Plate, tau: float) -> tuple[float, float, float]:
        """Wrench (F_x, F_y, M) in the part frame that carries the stuck part at τ."""
        pose, vel = plate.at(seg, tau)
        ax, ay, alpha = seg.accel_at(tau)
        cx, cy, phi = self.lab_pose(pose)
        rx, ry = cx - pose[0], cy - pose[1]
        om2 = vel[2] * vel[2]
        m = self.part.mass_kg
        fx, fy = m * (ax - alpha * ry - om2 * rx), m * (ay + alpha * rx - om2 * ry)
        c, s = math.cos(phi), math.sin(phi)
        return c * fx + s * fy, -s * fx + c * fy, self.part.inertia_kg_m2 * alpha

    def _twist(self, y: list[float] | np.ndarray, plate: Pose,
               vel: tuple[float, float, float]) -> tuple[float, float, float]:  # fmt: skip
        """Relative twist (w_x, w_y lab; ω_r) of a slipping part with lab state y."""
        rx, ry = y[0] - plate[0], y[1] - plate[1]
        return y[3] - (vel[0] - vel[2] * ry), y[4] - (vel[1] + vel[2] * rx), y[5] - vel[2]

    def _norm(self, w: tuple[float, float, float]) -> float:
        """Twist size √(|w|² + (I/m)·ω²) (m/s): kinetic energy per mass."""
        return math.sqrt(self._dot(w, w))

    # --- one segment ------------------------------------------------------
    def run(self, seg: Segment, plate: Plate) -> None:
        """Advance through ``seg``; ``plate`` holds the plate at its start and the velocity before."""
        tau = 0.0
        if seg.velocity != plate.velocity and self.stuck:  # a corner: the part cannot follow
            self.lab = self._carried(plate.pose, plate.velocity)
            self.stuck = False
            self._stop = _STOP * self._norm(self._twist(self.lab, plate.pose, seg.velocity))
        for _ in range(10_000):
            if tau >= seg.duration_s:
                return
            if self.stuck:
                start = self._breakaway(seg, plate, tau)
                if start is None:
                    return
                tau = start
                pose, vel = plate.at(seg, tau)
                self.lab = self._carried(pose, vel)
                self.stuck = False
                if seg.turns or not seg.smooth:  # else the 1-D closed form starts it
                    self._seed(seg, plate, tau)
            else:
                tau = self._slip(seg, plate, tau)
        raise RuntimeError("planar stick-slip: no progress within a segment")

    def _breakaway(self, seg: Segment, plate: Plate, tau: float) -> float | None:
        """First time ≥ τ in the segment where the static limit surface no longer holds the part."""
        patch, stress = self.part.patch, self._tau_s
        if seg.smooth and not seg.turns:  # constant wrench m·a, a pure force
            a = seg.accel
            return tau if math.hypot(a[0], a[1]) > self.part.friction.static_accel_m_s2 else None
        times = np.linspace(tau, seg.duration_s, 2 if seg.smooth else _BREAKAWAY_SAMPLES + 1)
        before = tau
        for t in times.tolist():
            if not patch.holds(*self._required(seg, plate, t), stress):
                if t == tau:
                    return tau
                return float(brentq(lambda u: patch.gauge(*self._required(seg, plate, u))[0] - stress,
                                    before, t, xtol=1e-15 * seg.duration_s))  # fmt: skip
            before = t
        return None

    def _seed(self, seg: Segment, plate: Plate, tau: float) -> None:
        """Start a slip from (near) zero twist along the breakaway direction of the required wrench."""
        _, (wx, wy, om) = self.part.patch.gauge(*self._required(seg, plate, tau))
        phi = self.lab[2]
        c, s = math.cos(phi), math.sin(phi)
        lx, ly = c * wx - s * wy, s * wx + c * wy
        size = self._norm((lx, ly, om))
        speed = self.part.friction.static_accel_m_s2 * _SEED_TIME_S / size
        self.lab[3] -= speed * lx
        self.lab[4] -= speed * ly
        self.lab[5] -= speed * om
        self._stop = 0.01 * speed * size

    def _slip(self, seg: Segment, plate: Plate, tau: float) -> float:
        """Slip from τ to the re-stick time or the segment's end; returns the time reached."""
        pose, vel = plate.at(seg, tau)
        w = self._twist(self.lab, pose, vel)
        a = seg.accel
        if seg.smooth and not seg.turns and w[2] == 0 and w[0] * a[1] == w[1] * a[0]:
            return self._slip_straight(seg, plate, tau, w)
        part = self.part
        patch, m, inertia, tau_k = part.patch, part.mass_kg, part.inertia_kg_m2, self._tau_k
        x0, y0, phi0 = self.lab[0], self.lab[1], self.lab[2]

        def rhs(t: float, y: np.ndarray) -> list[float]:
            p, v = plate.at(seg, t)
            rx, ry = x0 + y[0] - p[0], y0 + y[1] - p[1]
            wx, wy = y[3] - (v[0] - v[2] * ry), y[4] - (v[1] + v[2] * rx)
            phi = phi0 + y[2]
            c, s = math.cos(phi), math.sin(phi)
            ux, uy, mu, _ = patch.integrals(c * wx + s * wy, -s * wx + c * wy, y[5] - v[2])
            return [y[3], y[4], y[5], -tau_k * (c * ux - s * uy) / m,
                    -tau_k * (s * ux + c * uy) / m, -tau_k * mu / inertia]  # fmt: skip

        def twist(t: float, y: np.ndarray) -> tuple[float, float, float]:
            p, v = plate.at(seg, t)
            return self._twist([x0 + y[0], y0 + y[1], 0.0, y[3], y[4], y[5]], p, v)

        def twist_rate(t: float, y: np.ndarray) -> tuple[float, float, float]:
            """d(w, ω_r)/dt = (dv/dt − a_plate(c) − Ω ẑ×w, dω/dt − α)."""
            p, v = plate.at(seg, t)
            ax, ay, alpha = seg.accel_at(t)
            rx, ry = x0 + y[0] - p[0], y0 + y[1] - p[1]
            wx, wy, _ = twist(t, y)
            d = rhs(t, y)
            om = v[2]
            return (d[3] - (ax - alpha * ry - om * om * rx) + om * wy,
                    d[4] - (ay + alpha * rx - om * om * ry) - om * wx, d[5] - alpha)  # fmt: skip

        end, y, stopped = self._integrate(rhs, twist, twist_rate, tau, seg.duration_s,
                                          np.array([0.0, 0.0, 0.0, *self.lab[3:]]))  # fmt: skip
        self.lab = [x0 + float(y[0]), y0 + float(y[1]), phi0 + float(y[2]), *map(float, y[3:])]
        self.slip_time_s += end - tau
        if stopped:
            self._settle(seg, plate, end)
        return end

    def _dot(self, a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
        return a[0] * b[0] + a[1] * b[1] + self.part.inertia_kg_m2 / self.part.mass_kg * a[2] * b[2]

    def _resolution(self, y: np.ndarray) -> float:
        """The step control's absolute error scale of the twist (atol + rtol·|v| per velocity, m/s)."""
        r0, r1, r2 = (_ATOL[3:6] * (self._rtol / RTOL) + self._rtol * np.abs(y[3:6])).tolist()
        return math.sqrt(self._dot((r0, r1, r2), (r0, r1, r2)))

    def _integrate(self, rhs: Callable[[float, np.ndarray], list[float]],
                   twist: Callable[[float, np.ndarray], tuple[float, float, float]],
                   rate: Callable[[float, np.ndarray], tuple[float, float, float]],
                   t: float, t_end: float, y: np.ndarray) -> tuple[float, np.ndarray, bool]:  # fmt: skip
        """DOP853 from t towards t_end until the twist vanishes; returns (time, state, vanished).

        Friction jumps where the twist passes zero, so no step may cross it: a
        step that reverses the twist is dropped and the integration restarts
        with its end at 0.9 of the linearly predicted time to zero (halved
        while no step fits), until the twist is below the stop threshold or
        its predicted time to zero below the time resolution (a twist at the
        rounding floor of the velocities).  A twist whose linear closest
        approach stays above half its size turns rather than vanishes (a near
        miss): the integration goes on towards t_end, the step that reversed
        it halved and at most half the twist's time scale |ξ|/|dξ/dt|.  A
        shrinking twist within _UNRESOLVED error scales of the velocities has
        vanished (its direction is lost in the steps' error).
        """
        bound = t_end
        previous = twist(t, y)
        factor = 0.9
        first_step: float | None = None
        for _ in range(1000):
            begin = t
            stepper = DOP853(rhs, t, y, bound, rtol=self._rtol, atol=_ATOL * (self._rtol / RTOL),
                             first_step=first_step)  # fmt: skip
            first_step = None
            reversed_ = False
            tried = 0.0
            while stepper.status == "running":
                stepper.step()
                if stepper.status == "failed":
                    raise RuntimeError(f"planar stick-slip: integration failed at t = {t}")
                now = twist(stepper.t, stepper.y)
                if self._dot(now, previous) <= 0:
                    reversed_, tried = True, stepper.t - t
                    break
                t, y, previous = stepper.t, stepper.y, now
                floor = _ROUNDING * math.sqrt(self._dot((y[3], y[4], y[5]), (y[3], y[4], y[5])))
                size = math.sqrt(self._dot(now, now))
                if size <= max(self._stop, floor) or (size <= _UNRESOLVED * self._resolution(y)
                                                      and self._dot(now, rate(t, y)) < 0):  # fmt: skip
                    return t, y, True
            if not reversed_ and t >= t_end:
                return t, y, False
            d = rate(t, y)
            size2, rate2, along = self._dot(previous, previous), self._dot(d, d), self._dot(previous, d)
            to_zero = -along / rate2 if rate2 > 0 else 0.0
            if not to_zero > 0 or size2 - along * along / rate2 >= _MISS2 * size2:
                # the twist turns rather than vanishes (a near miss): on in time, steps within its turn
                floor = _ROUNDING * math.sqrt(self._dot((y[3], y[4], y[5]), (y[3], y[4], y[5])))
                if math.sqrt(size2) <= _NEAR_ZERO * max(self._stop, floor):
                    return t, y, True
                bound = t_end
                if reversed_:
                    first_step = 0.5 * min(tried, math.sqrt(size2 / rate2) if rate2 > 0 else tried, t_end - t)
                continue
            factor = 0.9 if t > begin else 0.5 * factor  # no step fitted: aim shorter
            if factor * to_zero <= 1e-15 * t_end:  # it vanishes within the time resolution
                return t, y, True
            bound = min(t_end, t + factor * to_zero)
        raise RuntimeError("planar stick-slip: the twist does not vanish")

    def _settle(self, seg: Segment, plate: Plate, tau: float) -> None:
        """The twist has vanished at τ: sticks if the static surface holds it, else slips on."""
        pose, _ = plate.at(seg, tau)
        self.pose = self.plate_pose(pose)
        self.stuck = True
        if not self.part.patch.holds(*self._required(seg, plate, tau), self._tau_s):
            self.lab = self._carried(pose, seg.velocity_at(tau))
            self.stuck = False
            self._seed(seg, plate, tau)

    def _slip_straight(self, seg: Segment, plate: Plate, tau: float,
                       w: tuple[float, float, float]) -> float:  # fmt: skip
        """Sliding along a fixed line: the 1-D closed form (DESIGN §4) along that line."""
        a = seg.accel
        speed = math.hypot(w[0], w[1])
        ex, ey = (w[0] / speed, w[1] / speed) if speed else (a[0], a[1])
        norm = math.hypot(ex, ey)
        if norm == 0:
            self.pose, self.stuck = self.plate_pose(plate.at(seg, tau)[0]), True
            return tau
        ex, ey = ex / norm, ey / norm
        friction = self.part.friction
        w_along, a_along = w[0] * ex + w[1] * ey, a[0] * ex + a[1] * ey
        a_s = friction.static_accel_m_s2
        if w_along == 0 and abs(a_along) <= a_s:  # at rest relative to a plate it can follow
            stuck, rel, s, slip = True, 0.0, 0.0, 0.0
        else:  # the closed form of :func:`advance_interval`, scalar
            stuck, rel, s, slip, _, _ = kernels.contact_interval(
                False, w_along, 0.0, 0.0, a_s, 0, a_along, seg.duration_s - tau, 0.0, a_s,
                friction.kinetic_ratio, 0.0, _NO_DRAWS)  # fmt: skip
        p0, _ = plate.at(seg, tau)
        p1, v1 = plate.at(seg, seg.duration_s)
        # the part: where it started plus the plate's displacement plus the relative slide
        cx = self.lab[0] + (p1[0] - p0[0]) + s * ex
        cy = self.lab[1] + (p1[1] - p0[1]) + s * ey
        self.lab = [cx, cy, self.lab[2], v1[0] + rel * ex, v1[1] + rel * ey, 0.0]
        self.slip_time_s += slip
        if stuck:
            self.pose = self.plate_pose(p1)
            self.stuck = True
        return seg.duration_s
