"""Which axis to step next, which way, in which mode, how often: pose control (docs/pose-control.md).

Pure: poses in, a burst (or the verdict) out; no I/O, no clock.  x and y
steps translate every part equally; a θ step turns the plate about O, which
turns and orbits the parts outside the dead zone and leaves those inside it
stuck (:mod:`feeder.pose_response`).  One part: turn first (at a *station*
outside the dead zone, moving there if needed), then translate to the target
(the turn's orbit is corrected by the translations; translations never turn).
The θ bursts and the stations: :mod:`feeder.pose_turns`.
Every burst aims short with a pessimistic (mean + 2σ) step, like the 1-D
policy, and is cut where its path with the largest plausible step
(:meth:`~feeder.pose_gain.GainFilter.bound`: at least the seed's upper end until two bursts
agree) would take a part out of the travel, or one already outside it further out
(:meth:`~feeder.travel.Travel.keeps`); a θ burst also where its pessimistic path would bring two
parts' footprints within :data:`~feeder.pose_turns.CLEARANCE_M` (x and y bursts move every part
alike).
Two parts: see :mod:`feeder.pose_pair`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from feeder.footprint import gap_m
from feeder.plant.planar import PlanarPart
from feeder.pose import Pose
from feeder.pose_burst import MAX_BURST_STEPS, AxisBurst, Finish, carry_refusal
from feeder.pose_response import ResponseModel, physical_period_rad
from feeder.pose_turns import CLEARANCE_M, TurnPlanner
from feeder.travel import Travel

DEFAULT_TOLERANCE_M = 1e-6
DEFAULT_TOLERANCE_RAD = math.radians(0.1)
PROBE_FRACTION = 1 / 8
"""Until an x or y step has been learned (a fresh state, a new device), its bursts aim at most
this fraction of the way: a real device up to 8× the physics' seed (the stack's gain, the
contact; a k× step carries a whole-way burst k − 1 times the way past the target, out of the
travel and the camera's view) reaches the target at most; two alike bursts lift it
(:data:`~feeder.pose_gain.CONFIRM_BURSTS`: one may have read another motion)."""


@dataclass
class _Job:
    targets: dict[int, Pose]
    bursts: int = 0
    notes: list[str] = field(default_factory=list)
    direction: int = 0
    """The last burst's direction (+1/−1; 0 before the first)."""
    trips: set[int] = field(default_factory=set)
    """Parts (indices) on their way to a turning station for a turn they needed: they go on and
    turn there even when a reading puts the angle within the tolerance (:meth:`PosePlanner.part_burst`)."""


class PosePlanner:
    """The next burst from measured poses and target poses (part id → pose; ids count from 1).

    model: per-step response, seeded from the plant and learned online.
    travel: the centre's allowed range.  tolerance_m: radius around the target
    centre; tolerance_rad: angle, modulo ``symmetry_rad`` (default: the part's
    physical symmetry; 2π for a marked part, 0 for a disc: any angle).
    part: the geometry (footprint, for the symmetry and the overlap check).
    turns: the θ bursts, and where a part turns (:class:`~feeder.pose_turns.TurnPlanner`).
    """

    def __init__(
        self,
        model: ResponseModel,
        travel: Travel,
        part: PlanarPart,
        tolerance_m: float = DEFAULT_TOLERANCE_M,
        tolerance_rad: float = DEFAULT_TOLERANCE_RAD,
        symmetry_rad: float | None = None,
        max_bursts: int = 400,
    ) -> None:
        self.model = model
        self.travel = travel
        self.part = part
        self.tolerance_m = tolerance_m
        self.tolerance_rad = tolerance_rad
        self.symmetry_rad = physical_period_rad(part) if symmetry_rad is None else symmetry_rad
        self.max_bursts = max_bursts
        self._job: _Job | None = None
        self.turns = TurnPlanner(model, travel, part, tolerance_m, tolerance_rad, self.symmetry_rad)

    # --- the contract ------------------------------------------------------
    def check(self, targets: dict[int, Pose], poses: list[Pose]) -> str | None:
        """Why these targets cannot be reached from these poses, or None."""
        for pid, target in targets.items():
            if not 1 <= pid <= len(poses):
                return f"part {pid} is not on the plate ({len(poses)} parts seen)"
            if not self.travel.contains(target[0], target[1]):
                return (
                    f"target of part {pid} at ({target[0]:.4g}, {target[1]:.4g}) m lies outside the travel "
                    f"{self.travel.describe()}"
                )
        if len(targets) > 2:
            return "at most two parts can be placed together"
        crowded = self._crowded_target(targets, poses)
        if crowded is not None:
            return crowded
        if len(targets) == 2:
            from feeder.pose_pair import pair_refusal

            return pair_refusal(self, targets, poses)
        pid, target = next(iter(targets.items()))
        if abs(self.turns.angle_error(poses[pid - 1], target)) <= self.tolerance_rad:
            return self._carried_out(poses, pid - 1, target)
        if self.turns.station_radius_m is None:  # a turn is needed (a disc never needs one)
            return "no θ mode turns the part anywhere within the travel"
        return None

    def _carried_out(self, poses: list[Pose], i: int, target: Pose) -> str | None:
        """Why translating part ``i`` to ``target`` would carry another part out of the travel (one
        already outside: further out), or None.  x and y bursts move every part alike, by the way
        less the tolerance at least along each axis."""
        pose = poses[i]
        shift = [
            math.copysign(max(abs(t - p) - self.tolerance_m, 0.0), t - p)
            for t, p in zip(target[:2], pose[:2], strict=True)
        ]
        for k, q in enumerate(poses):
            if k != i and not self.travel.keeps(q, (q[0] + shift[0], q[1] + shift[1], q[2])):
                return carry_refusal(
                    self.travel, f"moving part {i + 1} to ({target[0]:.4g}, {target[1]:.4g}) m", k, q
                )
        return None

    def _crowded_target(self, targets: dict[int, Pose], poses: list[Pose]) -> str | None:
        """Why a target's footprint comes within :data:`CLEARANCE_M` of another target, or None;
        parts already closer may stay as close.  A part without a target is no obstacle here:
        x/y bursts carry it along (it will not be where it lies now), and θ bursts are cut before
        it comes that close (:meth:`~feeder.pose_turns.TurnPlanner.theta_burst`)."""
        patch = self.part.patch
        for pid, target in targets.items():
            for other, there in targets.items():
                if other == pid:
                    continue
                gap = gap_m(patch, target, there)
                if gap < min(CLEARANCE_M, gap_m(patch, poses[pid - 1], poses[other - 1])):
                    near = "overlaps" if gap == 0 else f"comes within {gap:.3g} m of"
                    return (
                        f"the target of part {pid} at ({target[0]:.4g}, {target[1]:.4g}) m {near} part "
                        f"{other}'s target: parts keep {CLEARANCE_M:.3g} m apart for the camera to see "
                        "them apart"
                    )
        return None

    def next_burst(self, poses: list[Pose], targets: dict[int, Pose]) -> AxisBurst | Finish:
        """The next burst towards ``targets``, or Finish."""
        if self._job is None or self._job.targets != targets:
            self._job = _Job(dict(targets))
            reason = self.check(targets, poses)
            if reason is not None:
                return Finish("unreachable", reason)
        if self._job.bursts >= self.max_bursts:
            return Finish("unreachable", f"no convergence after {self._job.bursts} bursts")
        if len(targets) == 2:
            from feeder.pose_pair import next_pair_burst

            nxt = next_pair_burst(self, poses, targets)
        else:
            pid, target = next(iter(targets.items()))
            nxt = self.part_burst(poses, pid - 1, target)
        if nxt is None:
            return Finish("done", "every part within tolerance")
        if isinstance(nxt, AxisBurst):
            self._job.bursts += 1
            self._job.direction = nxt.direction
        return nxt

    def burst_effect(self, burst: AxisBurst, poses: list[Pose]) -> list[tuple[float, float]]:
        """Per part, how far (m) and by how much (rad, size) ``burst`` should move and turn it:
        its first step's predicted effect times the steps (cheap; not the stepped
        :meth:`~feeder.pose_response.ResponseModel.predict`)."""
        model, n = self.model, burst.steps
        if burst.axis != "theta":
            return [(n * model.step_m(burst.axis, burst.direction, burst.mode)[0], 0.0)] * len(poses)
        out = []
        for x, y, psi in poses:
            step = model.turn_step(burst.direction, burst.mode, x, y, psi)
            out.append(
                (n * math.hypot(step.radial_m, step.orbit_rad * math.hypot(x, y)), n * abs(step.turn_rad))
            )
        return out

    def learn(self, burst: AxisBurst, before: list[Pose], after: list[Pose]) -> None:
        """Fold in what ``burst`` did to every part (readings of one burst: alike, they confirm
        nothing, :data:`~feeder.pose_gain.CONFIRM_BURSTS`)."""
        token = object()
        for b, a in zip(before, after, strict=True):
            unwrapped = (a[0], a[1], b[2] + self.turns.angle_difference(a[2], b[2]))
            self.model.learn(burst.axis, burst.direction, burst.mode, burst.steps, b, unwrapped, token)

    def estimates_json(self) -> dict[str, object]:
        return {"gains": self.model.estimates_json(), "station_radius_m": self.turns.station_radius_m}

    # --- one part ----------------------------------------------------------
    def part_burst(self, poses: list[Pose], i: int, target: Pose) -> AxisBurst | Finish | None:
        """Next burst for part ``i`` alone (None: within tolerance).

        A part sent towards a turning station goes on until it turns there, even when a reading on
        the way puts its angle within the tolerance: the angle read after a translation differs
        by ~0.01–0.02° (the burst, the readings), so a part 0.093° off at O (0.09° tolerance) went
        ~20 x steps out, read within the tolerance, came back, read 0.093° again, and so on until
        the reversals ended the move "oscillating" (2 of 4 runs of a −10° turn at O).  The trip
        ends with its turn (a θ burst, aimed at the whole error), or where no θ burst improves
        the angle.
        """
        pose = poses[i]
        distance = math.hypot(pose[0] - target[0], pose[1] - target[1])
        turn = self.turns.angle_error(pose, target)
        trips = self._job.trips if self._job is not None else set()
        if abs(turn) > self.tolerance_rad or (i in trips and turn != 0):
            nxt = self.turn_burst(poses, i, turn, target[:2])
            if abs(turn) > self.tolerance_rad or self._trip_goes_on(nxt, pose, turn):
                if isinstance(nxt, AxisBurst) and nxt.axis != "theta":
                    trips.add(i)
                else:
                    trips.discard(i)
                return nxt
        trips.discard(i)  # within the tolerance, turned as well as θ can here: the trip is over
        if distance > self.tolerance_m:
            return self.translate_burst(poses, i, (target[0], target[1]), exact=True)
        return None

    def _trip_goes_on(self, nxt: AxisBurst | Finish, pose: Pose, turn: float) -> bool:
        """On a trip, the angle within the tolerance: whether ``nxt`` (:meth:`turn_burst`'s answer)
        still serves the turn: a θ burst, or a translation on towards the station from where the
        part does not turn (where it does and no θ burst improves the angle, the turn is done)."""
        if not isinstance(nxt, AxisBurst):
            return False
        return nxt.axis == "theta" or not self.turns.turns_here(pose, 1 if turn > 0 else -1)

    def turn_burst(
        self,
        poses: list[Pose],
        i: int,
        turn: float,
        then_xy: tuple[float, float],
    ) -> AxisBurst | Finish:
        """Turn part ``i`` by ``turn`` rad: here if it can, else move to a station first."""
        pose = poses[i]
        radius = self.turns.update_station()
        if radius is None:
            return Finish("unreachable", "no θ mode turns the part anywhere within the travel")
        blocked = None  # why turning here cannot go on (a neighbour): a station may have room
        if self.turns.turns_here(pose, 1 if turn > 0 else -1):
            burst = self.turns.theta_burst(poses, i, turn)
            if isinstance(burst, AxisBurst):
                return burst
            blocked = burst
        station = self.turns.station(poses, i, turn, then_xy)
        if station is None:
            return blocked or Finish(
                "unreachable",
                f"no turning station (radius {radius:.3g} m) whose turn keeps every part "
                f"within the travel and {CLEARANCE_M:.3g} m apart",
            )
        return self.translate_burst(poses, i, station, exact=False)

    def translate_burst(
        self, poses: list[Pose], i: int, goal: tuple[float, float], exact: bool
    ) -> AxisBurst | Finish:
        """x or y burst bringing part ``i`` towards ``goal``; ``exact``: aim short, end with fine steps.

        The axis that goes on in the last burst's direction first, else the larger error: the
        daemon counts every change of direction (whatever the axis) as a reversal and ends a move
        after 4 per axis as "oscillating" (a pair's way out to its anchor and back, x and y
        alternating in opposite directions, once took 13).
        """
        pose = poses[i]
        errors = {"x": goal[0] - pose[0], "y": goal[1] - pose[1]}
        last = self._job.direction if self._job is not None else 0
        carried: tuple[str, int] | None = None  # the first burst another part's travel stopped
        for axis in sorted(errors, key=lambda a: (errors[a] * last < 0, -abs(errors[a]))):
            error = errors[axis]
            if error == 0:
                continue
            direction = 1 if error > 0 else -1
            burst, stop = self._axis_burst(poses, axis, direction, abs(error), exact)
            if burst is not None:
                return burst
            if stop is not None and stop != i and carried is None:
                carried = (f"moving part {i + 1} further in {'+' if direction > 0 else '−'}{axis}", stop)
        if carried is not None:
            return Finish(
                "unreachable", carry_refusal(self.travel, carried[0], carried[1], poses[carried[1]])
            )
        if not exact:  # the station is within a step of here: turn here after all
            return Finish("unreachable", "the turning station is closer than one step")
        return Finish(
            "unreachable",
            f"fine steps cannot bring part {i + 1} within {self.tolerance_m:.3g} m "
            f"of ({goal[0]:.4g}, {goal[1]:.4g}) m within the travel",
        )

    # --- pieces ------------------------------------------------------------
    def _axis_burst(
        self, poses: list[Pose], axis: str, direction: int, distance: float, exact: bool
    ) -> tuple[AxisBurst | None, int | None]:
        """The burst along ``axis`` covering ``distance`` (m), or None; with the part (index) whose
        travel left no step of the finest mode that had some to take, if one did."""
        stop = None
        modes = self.model.modes(axis)
        fine = modes[-1]
        fine_step, _ = self.model.step_m(axis, direction, fine)
        for mode in modes:
            step, std = self.model.step_m(axis, direction, mode)
            high = step + 2 * std
            if mode != fine and step > fine_step:
                steps = math.floor(distance / high) - 1 if exact else round(distance / step)
            elif mode == fine:
                steps = round(distance / max(step, 1e-12))
            else:
                continue
            if not self.model.learned(axis, direction, mode):
                steps = min(steps, max(1, math.floor(PROBE_FRACTION * distance / step)))
            cut, by = self.travel_cut(poses, axis, direction, mode, min(steps, MAX_BURST_STEPS))
            if cut >= 1:
                return AxisBurst(axis, direction, cut, mode), None
            if steps >= 1:
                stop = by
        return None, stop

    def travel_cut(
        self, poses: list[Pose], axis: str, direction: int, mode: str, steps: int
    ) -> tuple[int, int | None]:
        """``steps`` of an x or y burst cut so that every part's end stays within the travel (one
        outside it goes no further out: :meth:`Travel.keeps`) with the largest step the burst
        plausibly makes (:meth:`~feeder.pose_response.ResponseModel.step_bound_m`, at least the
        aim's mean + 2σ), with the part (index) that cut it, if one did.  (Coarse x and y run at
        ~0.5 mm per camera frame: the daemon's watch cannot stop a part the plan sends out.)"""
        step, std = self.model.step_m(axis, direction, mode)
        high = max(step + 2 * std, self.model.step_bound_m(axis, direction, mode))
        # the finest steps may end beyond the edge by their bound less the tolerance: a part
        # more than the tolerance short of a target on the edge always has one (it had none
        # between 0.9 and 2.2 µm short, the bound 1.6× the seed: `unreachable` in 9 of 16 moves
        # to the edge of a re-audit); its mean end then lies within the tolerance of the target
        fine = mode == self.model.modes(axis)[-1]
        return self._within_travel(
            poses, axis, direction, high, steps, max(high - self.tolerance_m, 0) if fine else 0
        )

    def _within_travel(
        self, poses: list[Pose], axis: str, direction: int, high: float, steps: int, slack: float = 0.0
    ) -> tuple[int, int | None]:
        """``steps`` cut so that every part's end after steps of ``high`` (m) stays within the
        travel, give or take ``slack`` (m) for a part within it (one outside it goes no further
        out: :meth:`Travel.keeps`), with the part (index) that cut it, if one did."""
        k = 0 if axis == "x" else 1
        lo, hi = self.travel.x_m if axis == "x" else self.travel.y_m
        by = None
        for j, p in enumerate(poses):
            room = (hi - p[k]) if direction > 0 else (p[k] - lo)
            fits = math.floor((room + slack) / high) if room >= 0 else 0
            if fits < steps:
                steps, by = fits, j
        return steps, by
