"""Parts on a plate moving in x, y and θ: event-driven planar stick-slip of their poses (DESIGN §9).

Frames: the plate frame has its origin at the rotation centre O and coincides
with the lab frame at t = 0; a part's pose (x, y, ψ) is its centre and the
direction of its first dimension, in the plate frame (m, m, rad).  The plate
moves as in :mod:`feeder.plant.plate_motion`.

A part sticks while the wrench the plate must exert to carry it,
W = (m·a_plate(c), I·α) (c its centre, α the plate's angular acceleration),
lies inside the static limit surface (:mod:`feeder.plant.limit_surface`,
stress τ_s = m·a_s/A).  Otherwise it slips: its rigid-body motion in the lab
frame, m·dv/dt = F, I·dω/dt = M, with the kinetic friction (τ_k = r·τ_s)
integrated over the patch at the relative twist (w, ω_r) = (v − v_plate(c),
ω − Ω).  It re-sticks when the relative twist vanishes and W lies inside the
static surface again.

Events are exact: velocity jumps at segment corners; breakaway from stick is
the root of g(W(t)) = τ_s (sampled, then Brent); slip episodes are integrated
with DOP853 (rtol 1e-10) to the time the twist vanishes (terminal event).
Where the sliding direction cannot turn (no rotation of the plate in the
segment, no relative spin, plate acceleration along the sliding direction: every
x or y drive) the segment is solved in the 1-D closed form of
:func:`feeder.plant.stick_slip.advance_interval` (its scalar form,
:func:`feeder.plant.kernels.contact_interval`), so a pure translation is the
1-D model (DESIGN §4) to rounding.

With numba (extra ``fast``; :func:`feeder.plant.kernels.enabled`) the same
solver runs compiled on arrays (:mod:`feeder.plant.planar_kernels`); the code
here is the reference and the fallback.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.integrate import DOP853
from scipy.optimize import brentq

from feeder.errors import InputError
from feeder.parts import Part
from feeder.plant import kernels, limit_surface_kernels, planar_arrays, slip_kernels
from feeder.plant import planar_kernels as pk
from feeder.plant.limit_surface import Patch
from feeder.plant.plate_motion import PlanarMotion, Segment
from feeder.plant.stick_slip import Friction

Pose = tuple[float, float, float]
_SEED_TIME_S = 1e-12
"""A part breaking loose starts with the twist a_s·1e-12 s along its breakaway direction."""
_STOP = 1e-10
"""A slip ends when the twist has fallen below this fraction of its value at the start."""
_BREAKAWAY_SAMPLES = 16
_ROUNDING = 1e-14
"""A twist this small relative to the part's lab velocity is rounding: it has vanished."""
_SKIP_HELD = True
"""Skip samples in bulk while every part is surely held (tests switch it off to compare)."""
_HELD_MARGIN = 1 - 1e-6
_MISS2 = slip_kernels._MISS2
"""A twist whose linear closest approach stays above half its size (squared: this) turns, not vanishes."""
_NEAR_ZERO = slip_kernels._NEAR_ZERO
_UNRESOLVED = slip_kernels._UNRESOLVED
"""A shrinking twist within this many absolute error scales of the velocities has vanished."""
_NO_DRAWS = np.zeros(0)
_DISC_NODES = limit_surface_kernels.DISC_NODES
_ATOL = np.array([1e-16, 1e-16, 1e-13, 1e-13, 1e-13, 1e-9])
"""Absolute tolerances of (c − c₀, φ − φ₀, v, ω) at :data:`RTOL` (scaled with rtol)."""
RTOL = 1e-10
"""Relative tolerance of the slip episodes' integration (:func:`simulate`)."""


@dataclass(frozen=True)
class PlanarPart:
    """A rigid part on the plate: patch, mass (kg), inertia about its centre (kg·m²), friction, pose."""

    patch: Patch
    mass_kg: float
    inertia_kg_m2: float
    friction: Friction
    pose: Pose = (0.0, 0.0, 0.0)

    @classmethod
    def from_part(cls, part: Part, friction: Friction, pose: Pose = (0.0, 0.0, 0.0),
                  shape: str = "rectangle") -> PlanarPart:  # fmt: skip
        """Rectangle L×W, or a disc of diameter L (needs L = W), thickness T, the part's density."""
        if shape == "disc":
            if part.length_m != part.width_m:
                raise InputError("--part", f"a disc needs L = W (its diameter), got {part.label}")
            patch = Patch("disc", part.length_m, part.length_m)
            mass = part.density_kg_m3 * patch.area_m2 * part.thickness_m
            return cls(patch, mass, mass * part.length_m**2 / 8, friction, pose)
        patch = Patch("rectangle", part.length_m, part.width_m)
        inertia = part.mass_kg * (part.length_m**2 + part.width_m**2) / 12
        return cls(patch, part.mass_kg, inertia, friction, pose)

    @property
    def static_stress_pa(self) -> float:
        """τ_s = m·a_s/A: the friction stress over the patch at breakaway."""
        return self.mass_kg * self.friction.static_accel_m_s2 / self.patch.area_m2


def _outline(part: PlanarPart) -> tuple[np.ndarray, np.ndarray]:
    """(corner points (4, 2), unit axes (2, 2)) of a rectangle part in the plate frame."""
    x, y, psi = part.pose
    axes = np.array([[math.cos(psi), math.sin(psi)], [-math.sin(psi), math.cos(psi)]])
    half = np.array([0.5 * part.patch.length_m, 0.5 * part.patch.width_m])
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]])
    return np.array([x, y]) + (signs * half) @ axes, axes


def _overlap(a: PlanarPart, b: PlanarPart) -> bool:
    """True if the two footprints share interior points (touching is allowed)."""
    ca, cb = np.array(a.pose[:2]), np.array(b.pose[:2])
    if a.patch.shape == "disc" and b.patch.shape == "disc":
        return bool(np.linalg.norm(ca - cb) < 0.5 * (a.patch.length_m + b.patch.length_m))
    if a.patch.shape == "disc":
        a, b = b, a
    corners_a, axes_a = _outline(a)
    if b.patch.shape == "disc":  # nearest point of the rectangle to the disc's centre
        local = axes_a @ (np.array(b.pose[:2]) - np.array(a.pose[:2]))
        half = np.array([0.5 * a.patch.length_m, 0.5 * a.patch.width_m])
        return bool(np.linalg.norm(local - np.clip(local, -half, half)) < 0.5 * b.patch.length_m)
    corners_b, axes_b = _outline(b)
    for axis in (*axes_a, *axes_b):  # separating axis theorem
        pa, pb = corners_a @ axis, corners_b @ axis
        if pa.max() <= pb.min() or pb.max() <= pa.min():
            return False
    return True


def check_overlaps(parts: list[PlanarPart]) -> None:
    """InputError naming the first two parts (by index) whose footprints overlap."""
    for i, a in enumerate(parts):
        for j in range(i + 1, len(parts)):
            if _overlap(a, parts[j]):
                raise InputError("pose", f"parts {i} and {j} overlap at poses {a.pose} and {parts[j].pose}")


class _Plate:
    """The plate's pose (x_O, y_O, θ) at the start of the current segment, and its velocity."""

    def __init__(self, velocity: tuple[float, float, float]) -> None:
        self.pose = (0.0, 0.0, 0.0)
        self.velocity = velocity

    def at(self, seg: Segment, tau: float) -> tuple[Pose, tuple[float, float, float]]:
        d = seg.position(tau)
        return (self.pose[0] + d[0], self.pose[1] + d[1], self.pose[2] + d[2]), seg.velocity_at(tau)

    def finish(self, seg: Segment) -> None:
        self.pose, self.velocity = self.at(seg, seg.duration_s)


class _PartState:
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

    def _required(self, seg: Segment, plate: _Plate, tau: float) -> tuple[float, float, float]:
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
    def run(self, seg: Segment, plate: _Plate) -> None:
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

    def _breakaway(self, seg: Segment, plate: _Plate, tau: float) -> float | None:
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

    def _seed(self, seg: Segment, plate: _Plate, tau: float) -> None:
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

    def _slip(self, seg: Segment, plate: _Plate, tau: float) -> float:
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

    def _settle(self, seg: Segment, plate: _Plate, tau: float) -> None:
        """The twist has vanished at τ: sticks if the static surface holds it, else slips on."""
        pose, _ = plate.at(seg, tau)
        self.pose = self.plate_pose(pose)
        self.stuck = True
        if not self.part.patch.holds(*self._required(seg, plate, tau), self._tau_s):
            self.lab = self._carried(pose, seg.velocity_at(tau))
            self.stuck = False
            self._seed(seg, plate, tau)

    def _slip_straight(self, seg: Segment, plate: _Plate, tau: float,
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


def _params(part: PlanarPart, rtol: float) -> np.ndarray:
    """The part's parameter row for :mod:`.planar_kernels`."""
    patch, friction = part.patch, part.friction
    return planar_arrays.part_params(patch.shape == "disc", patch.length_m, patch.width_m, part.mass_kg,
                          part.inertia_kg_m2, friction.static_accel_m_s2, friction.kinetic_ratio,
                          patch.area_m2, patch.polar_m3, patch.second_moments_m4, rtol)  # fmt: skip


class PlanarStickSlip:
    """Several parts on one plate, state kept across calls (plate frame = lab frame at t = 0).

    Two drivers of the same solver: :meth:`advance` for segments (ideal
    sawtooth, :func:`simulate`), :meth:`advance_sampled` for the plate's three
    motion channels sampled at a fixed rate (the streaming plant, like
    :meth:`feeder.plant.plant.Plant.advance`).  rtol: of the slip episodes.
    Compiled (:mod:`.planar_kernels`) if the kernels are enabled when it is built.
    """

    def __init__(self, parts: list[PlanarPart],
                 initial_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 rtol: float = RTOL) -> None:  # fmt: skip
        if not parts:
            raise InputError("parts", "at least one part is needed")
        check_overlaps(parts)
        self.parts = list(parts)
        self._elapsed = 0.0
        self._compiled = kernels.enabled()
        self._states = [_PartState(p, rtol) for p in parts]
        self._plate = _Plate(initial_velocity)
        # the compiled solver's state (:mod:`.planar_kernels`), used when kernels are enabled
        self._params = np.array([_params(p, rtol) for p in parts])
        self._array = np.array([planar_arrays.initial_state(p.pose, p.patch.radius_m) for p in parts])
        self._plate_array = np.array([0.0, 0.0, 0.0, *initial_velocity, 0.0])

    @property
    def elapsed_s(self) -> float:
        """Time run so far (s)."""
        return self._plate_array.item(planar_arrays.ELAPSED) if self._compiled else self._elapsed

    @property
    def plate_pose(self) -> Pose:
        """(x_O, y_O, θ) of the plate in the lab frame (m, m, rad)."""
        if self._compiled:
            x, y, theta = self._plate_array[:3].tolist()
            return x, y, theta
        return self._plate.pose

    @property
    def slip_time_s(self) -> list[float]:
        if self._compiled:
            return self._array[:, planar_arrays.SLIP].tolist()
        return [s.slip_time_s for s in self._states]

    @property
    def integration_steps(self) -> list[int]:
        """Dormand-Prince steps tried per part so far (compiled only: a cost gauge; else zeros)."""
        if self._compiled:
            return [int(n) for n in self._array[:, planar_arrays.STEPS]]
        return [0] * len(self._states)

    def poses(self) -> list[Pose]:
        """Each part's pose in the plate frame now."""
        if self._compiled:
            return [planar_arrays.plate_frame_pose(st, *self.plate_pose) for st in self._array]
        return [s.plate_pose(self._plate.pose) for s in self._states]

    def lab_poses(self) -> list[Pose]:
        """Each part's pose in the lab frame now (what a camera sees)."""
        if self._compiled:
            return [planar_arrays.lab_pose(st, *self.plate_pose) for st in self._array]
        return [s.lab_pose(self._plate.pose) for s in self._states]

    def stuck(self) -> list[bool]:
        if self._compiled:
            return [bool(st[planar_arrays.STUCK]) for st in self._array]
        return [s.stuck for s in self._states]

    def advance(self, segments: tuple[Segment, ...] | list[Segment], every: int = 1) -> np.ndarray:
        """Run the segments; plate-frame poses (parts, len(segments) // every, 3) every ``every`` segments."""
        if self._compiled:
            rows = [[s.duration_s, *s.velocity, *s.accel, *s.cosine, s.kappa] for s in segments]
            poses = np.empty((len(self.parts), len(rows) // every, 3))
            pk.run_segments(self._array, self._params, _DISC_NODES,
                            np.array(rows, dtype=float).reshape(len(rows), planar_arrays.SEG_SIZE),
                            self._plate_array, every, poses)  # fmt: skip
            return poses
        out = []
        for k, seg in enumerate(segments):
            for state in self._states:
                state.run(seg, self._plate)
            self._plate.finish(seg)
            self._elapsed += seg.duration_s
            if (k + 1) % every == 0:
                out.append(self.poses())
        return np.array(out, dtype=float).reshape(len(out), len(self._states), 3).transpose(1, 0, 2)

    def advance_sampled(self, velocity: np.ndarray, sample_rate_hz: float) -> np.ndarray:
        """Plate velocity samples (v_x, v_y, Ω) of shape (3, n), acceleration held between samples.

        Returns the parts' lab-frame poses (parts, n, 3) at each sample.  While
        every part is stuck and the plate's motion surely cannot break any of
        them loose (:meth:`_surely_held`), samples are skipped in bulk: the
        plate moves, the parts' plate-frame poses stay (what the per-sample
        solver would do, to rounding of the lab poses).
        """
        v = np.asarray(velocity, dtype=float)
        n = v.shape[1]
        if self._compiled:
            lab = np.empty((len(self.parts), n, 3))
            pk.run_sampled(self._array, self._params, _DISC_NODES, np.ascontiguousarray(v),
                           float(sample_rate_hz), self._plate_array, _SKIP_HELD, lab)  # fmt: skip
            return lab
        dt = 1.0 / sample_rate_hz
        start = np.concatenate([np.asarray(self._plate.velocity, dtype=float)[:, None], v[:, :-1]], axis=1)
        accel = (v - start) * sample_rate_hz  # as :func:`sampled`
        starts, accels, ends = start.T.tolist(), accel.T.tolist(), v.T.tolist()
        out = np.empty((len(self._states), n, 3))
        held: tuple[list[Pose], np.ndarray] | None = None
        k = 0
        while k < n:
            if _SKIP_HELD and all(state.stuck for state in self._states):
                poses = [state.pose for state in self._states]
                if held is None or held[0] != poses:
                    held = poses, self._surely_held(start, v, accel, k)
                stop = k + int(np.argmin(held[1][k - n :])) if not held[1][k - n :].all() else n
                if stop > k:
                    self._skip(start, accel, dt, k, stop, ends[stop - 1], out)
                    k = stop
                    continue
            seg = Segment(dt, tuple(starts[k]), tuple(accels[k]))
            for state in self._states:
                state.run(seg, self._plate)
            self._plate.finish(seg)
            # the sample itself, not v₀ + a·dt (which rounds differently): no corner at the next one
            self._plate.velocity = (ends[k][0], ends[k][1], ends[k][2])
            self._elapsed += dt
            out[:, k] = self.lab_poses()
            k += 1
        return out

    @property
    def compiled(self) -> bool:
        """True if this solver runs the compiled kernels (:mod:`.planar_kernels`)."""
        return self._compiled

    def advance_driven(self, command: np.ndarray, drive: np.ndarray, sample_rate_hz: float) -> np.ndarray:
        """Compiled only: DAC samples (3, n) through output stages and stack filters into
        :meth:`advance_sampled`; ``drive`` (3, k) per channel: coefficients, filter states and
        voltage (updated in place), plate units per stack metre (:func:`.planar_kernels.run_plant`)."""
        lab = np.empty((self._array.shape[0], command.shape[1], 3))
        pk.run_plant(command, drive, self._array, self._params, _DISC_NODES, sample_rate_hz,
                     self._plate_array, _SKIP_HELD, lab)  # fmt: skip
        return lab

    def _surely_held(self, start: np.ndarray, end: np.ndarray, accel: np.ndarray, k: int) -> np.ndarray:
        """Per sample from ``k`` on (length n): True where no stuck part can break loose.

        The force carrying a part at distance r from O is at most
        m·(|a_O| + |α|·r + max Ω²·r) over the sample (Ω is linear in it), the
        moment I·|α|; inside the diamond |F|/F₀ + |M|/M₀ ≤ 1 (inside the limit
        surface, :meth:`Patch.holds`) the part holds, with a margin.
        """
        n = start.shape[1]
        sure = np.ones(n, dtype=bool)
        a_lin = np.hypot(accel[0, k:], accel[1, k:])
        alpha = np.abs(accel[2, k:])
        spin2 = np.maximum(start[2, k:] ** 2, end[2, k:] ** 2)
        for state in self._states:
            part = state.part
            r = math.hypot(state.pose[0], state.pose[1])
            force = part.mass_kg * (a_lin + alpha * r + spin2 * r) / (state._tau_s * part.patch.area_m2)
            moment = part.inertia_kg_m2 * alpha / (state._tau_s * part.patch.polar_m3)
            sure[k:] &= force + moment <= _HELD_MARGIN
        return sure

    def _skip(self, start: np.ndarray, accel: np.ndarray, dt: float, k: int, stop: int,
              last: list[float], out: np.ndarray) -> None:  # fmt: skip
        """Samples k…stop−1 with every part held: the plate moves (trapezoid, as :meth:`_Plate.finish`)."""
        step = start[:, k:stop] * dt + 0.5 * accel[:, k:stop] * dt * dt  # Segment.position at its end
        before = np.asarray(self._plate.pose)[:, None]
        plate = np.cumsum(np.concatenate([before, step], axis=1), axis=1)[:, 1:]
        c, s = np.cos(plate[2]), np.sin(plate[2])
        for i, state in enumerate(self._states):
            x, y, psi = state.pose
            out[i, k:stop, 0] = plate[0] + c * x - s * y
            out[i, k:stop, 1] = plate[1] + s * x + c * y
            out[i, k:stop, 2] = plate[2] + psi
        self._plate.pose = (float(plate[0, -1]), float(plate[1, -1]), float(plate[2, -1]))
        self._plate.velocity = (last[0], last[1], last[2])
        for _ in range(stop - k):  # as the per-sample loop adds it
            self._elapsed += dt


@dataclass(frozen=True)
class PlanarRun:
    """Result of :func:`simulate`: per part, the plate-frame pose at the end of each period."""

    poses: np.ndarray  # (parts, periods, 3)
    start: np.ndarray  # (parts, 3)
    slip_fraction: np.ndarray  # (parts,)

    @property
    def changes(self) -> np.ndarray:
        """Pose change in each period (parts, periods, 3); the first period starts from ``start``."""
        return np.diff(np.concatenate([self.start[:, None, :], self.poses], axis=1), axis=1)


def simulate(parts: list[PlanarPart], motion: PlanarMotion) -> PlanarRun:
    """Run ``motion`` on the parts (each starting stuck at its pose); poses after each period."""
    solver = PlanarStickSlip(parts, motion.initial_velocity)
    poses = solver.advance(motion.segments, motion.segments_per_period)
    return PlanarRun(poses, np.array([p.pose for p in parts], dtype=float),
                     np.array(solver.slip_time_s) / solver.elapsed_s)  # fmt: skip
