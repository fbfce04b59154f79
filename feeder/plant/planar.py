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
solver runs compiled on arrays (:mod:`feeder.plant.planar_kernels`); the reference and
fallback is :mod:`feeder.plant.planar_reference`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feeder.errors import InputError
from feeder.plant import kernels, limit_surface_kernels, planar_arrays
from feeder.plant import planar_kernels as pk
from feeder.plant.planar_kernels import _HELD_MARGIN
from feeder.plant.planar_part import PlanarPart, Pose, check_overlaps
from feeder.plant.planar_reference import RTOL, PartState, Plate
from feeder.plant.plate_motion import PlanarMotion, Segment

_SKIP_HELD = True
"""Skip samples in bulk while every part is surely held (tests switch it off to compare)."""
_DISC_NODES = limit_surface_kernels.DISC_NODES


def _params(part: PlanarPart, rtol: float) -> np.ndarray:
    """The part's parameter row for :mod:`.planar_kernels`."""
    patch, friction = part.patch, part.friction
    return planar_arrays.part_params(
        patch.shape == "disc", patch.length_m, patch.width_m, part.mass_kg, part.inertia_kg_m2,
        friction.static_accel_m_s2, friction.kinetic_ratio, patch.area_m2, patch.polar_m3,
        patch.second_moments_m4, rtol,
    )  # fmt: skip


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
        self._states = [PartState(p, rtol) for p in parts]
        self._plate = Plate(initial_velocity)
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
            stress = part.static_stress_pa
            force = part.mass_kg * (a_lin + alpha * r + spin2 * r) / (stress * part.patch.area_m2)
            moment = part.inertia_kg_m2 * alpha / (stress * part.patch.polar_m3)
            sure[k:] &= force + moment <= _HELD_MARGIN
        return sure

    def _skip(self, start: np.ndarray, accel: np.ndarray, dt: float, k: int, stop: int,
              last: list[float], out: np.ndarray) -> None:  # fmt: skip
        """Samples k…stop−1 with every part held: the plate moves (trapezoid, as :meth:`Plate.finish`)."""
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
