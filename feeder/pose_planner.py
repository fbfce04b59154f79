"""Which axis to step next, which way, in which mode, how often: pose control (docs/pose-control.md).

Pure: poses in, a burst (or the verdict) out; no I/O, no clock.  x and y
steps translate every part equally; a θ step turns the plate about O, which
turns and orbits the parts outside the dead zone and leaves those inside it
stuck (:mod:`feeder.pose_response`).  One part: turn first (at a *station*
outside the dead zone, moving there if needed), then translate to the target
(the turn's orbit is corrected by the translations; translations never turn).
A turn steps θ's coarse and fine modes; a pair's orbit its anchoring ones when the
model has them (:meth:`~feeder.pose_response.ResponseModel.orbit_modes`).
Every burst aims short with a pessimistic (mean + 2σ) step, like the 1-D
policy, and is cut where its pessimistic path would take a part out of the
travel, or one already outside it further out (:meth:`~feeder.travel.Travel.keeps`); a θ
burst also where it would bring two parts' footprints within
:data:`CLEARANCE_M` (x and y bursts move every part alike).
Two parts: see :mod:`feeder.pose_pair`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from feeder.footprint import gap_m
from feeder.plant.planar import PlanarPart
from feeder.pose import Pose
from feeder.pose_response import ResponseModel, physical_period_rad
from feeder.travel import Travel
from feeder.vision.model import angle_difference

DEFAULT_TOLERANCE_M = 1e-6
DEFAULT_TOLERANCE_RAD = math.radians(0.1)
STATION_BAND_M = 40e-6
"""A part within this of its turning station's radius turns there."""
STATION_DIRECTIONS = 36
USEFUL_TURN = 0.25
"""A θ mode turns a part (a turn burst steps it, the turning station is where its fine mode does)
when one step turns the part by at least this fraction of ``tolerance_rad``."""
USEFUL_ORBIT = 0.02
"""An orbit step (two parts placed relative to each other, to half the tolerance) is worth a θ
burst when it moves the part by at least this fraction of ``tolerance_m``."""
MAX_BURST_STEPS = 2000
PROBE_FRACTION = 1 / 8
"""Until an x or y step has been learned (a fresh state, a new device), its bursts aim at most
this fraction of the way: a real device up to 8× the physics' seed (the stack's gain, the
contact; a k× step carries a whole-way burst k − 1 times the way past the target, out of the
travel and the camera's view) reaches the target at most; one learned burst lifts it."""
CLEARANCE_M = 40e-6
"""θ bursts and targets keep every two parts' footprints at least this far apart (m), or as far
as they are when already closer: the camera must see them apart.  Its blob search works on the
image shrunk 2–4× and its edge fits sample profiles reaching 10 px beyond each side
(:mod:`feeder.vision.locate`, :mod:`feeder.vision.edges`): 27 µm at the cameras' 2.7 µm/px, or a
neighbour merges the blobs ("overlapped or touching parts") or bends the fitted edge.  The rest
(13 µm) covers what the pessimistic prediction (mean + 2σ per step) misses and the last step
before the cut (a coarse θ step moves a 300 µm part's corner by a few µm)."""


@dataclass(frozen=True)
class AxisBurst:
    """``steps`` steps of ``axis`` in ``direction`` (+1/−1) with the waveform ``mode`` (coarse|fine;
    θ also anchor|anchor-fine, :data:`~feeder.pose_response.ANCHOR_MODES`)."""

    axis: str
    direction: int
    steps: int
    mode: str


@dataclass(frozen=True)
class Finish:
    """The move is over: status "done" (every target within tolerance) or "unreachable" with the reason."""

    status: str
    reason: str


@dataclass
class _Job:
    targets: dict[int, Pose]
    bursts: int = 0
    notes: list[str] = field(default_factory=list)
    direction: int = 0
    """The last burst's direction (+1/−1; 0 before the first)."""


class PosePlanner:
    """The next burst from measured poses and target poses (part id → pose; ids count from 1).

    model: per-step response, seeded from the plant and learned online.
    travel: the centre's allowed range.  tolerance_m: radius around the target
    centre; tolerance_rad: angle, modulo ``symmetry_rad`` (default: the part's
    physical symmetry; 2π for a marked part, 0 for a disc: any angle).
    part: the geometry (footprint, for the symmetry and the overlap check).
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
        self.station_radius_m = self._station_radius()

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
        if abs(self.angle_error(poses[pid - 1], target)) <= self.tolerance_rad:
            return self._carried_out(poses, pid - 1, target)
        if self.station_radius_m is None:  # a turn is needed (a disc never needs one)
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
                return self._carry_refusal(
                    f"moving part {i + 1} to ({target[0]:.4g}, {target[1]:.4g}) m", k, q
                )
        return None

    def _carry_refusal(self, moving: str, k: int, pose: Pose) -> str:
        """Why ``moving`` ("moving part 1 further in +x") cannot be: it would carry part ``k``
        (index), at ``pose``, out of the travel, or further out when it already lies outside."""
        further = "further " if any(self.travel.beyond(pose[0], pose[1])) else ""
        return (
            f"{moving} would carry part {k + 1} at ({pose[0]:.4g}, {pose[1]:.4g}) m {further}out of the "
            f"travel {self.travel.describe()}: the camera must keep seeing it"
        )

    def _crowded_target(self, targets: dict[int, Pose], poses: list[Pose]) -> str | None:
        """Why a target's footprint comes within :data:`CLEARANCE_M` of another target, or None;
        parts already closer may stay as close.  A part without a target is no obstacle here:
        x/y bursts carry it along (it will not be where it lies now), and θ bursts are cut before
        it comes that close (:meth:`_theta_within`)."""
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
        """Fold in what ``burst`` did to every part."""
        for b, a in zip(before, after, strict=True):
            unwrapped = (a[0], a[1], b[2] + self._angle_difference(a[2], b[2]))
            self.model.learn(burst.axis, burst.direction, burst.mode, burst.steps, b, unwrapped)

    def estimates_json(self) -> dict[str, object]:
        return {"gains": self.model.estimates_json(), "station_radius_m": self.station_radius_m}

    # --- one part ----------------------------------------------------------
    def part_burst(
        self, poses: list[Pose], i: int, target: Pose, anchored: tuple[int, ...] = ()
    ) -> AxisBurst | Finish | None:
        """Next burst for part ``i`` alone (None: within tolerance); ``anchored`` parts must not turn."""
        pose = poses[i]
        distance = math.hypot(pose[0] - target[0], pose[1] - target[1])
        turn = self.angle_error(pose, target)
        if abs(turn) > self.tolerance_rad:
            return self.turn_burst(poses, i, turn, target[:2], anchored)
        if distance > self.tolerance_m:
            return self.translate_burst(poses, i, (target[0], target[1]), exact=True)
        return None

    def turn_burst(
        self,
        poses: list[Pose],
        i: int,
        turn: float,
        then_xy: tuple[float, float],
        anchored: tuple[int, ...] = (),
    ) -> AxisBurst | Finish:
        """Turn part ``i`` by ``turn`` rad: here if it can, else move to a station first."""
        pose = poses[i]
        self.station_radius_m = self._station_radius()
        if self.station_radius_m is None:
            return Finish("unreachable", "no θ mode turns the part anywhere within the travel")
        blocked = None  # why turning here cannot go on (a neighbour): a station may have room
        if self._turns_here(pose, 1 if turn > 0 else -1):
            burst = self.theta_burst(poses, i, turn, anchored)
            if isinstance(burst, AxisBurst):
                return burst
            blocked = burst
        station = self._station(poses, i, turn, then_xy)
        if station is None:
            return blocked or Finish(
                "unreachable",
                f"no turning station (radius {self.station_radius_m:.3g} m) whose turn keeps every part "
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
            return Finish("unreachable", self._carry_refusal(carried[0], carried[1], poses[carried[1]]))
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
            cut, by = self._within_travel(poses, axis, direction, high, min(steps, MAX_BURST_STEPS))
            if cut >= 1:
                return AxisBurst(axis, direction, cut, mode), None
            if steps >= 1:
                stop = by
        return None, stop

    def _within_travel(
        self, poses: list[Pose], axis: str, direction: int, high: float, steps: int
    ) -> tuple[int, int | None]:
        """``steps`` cut so that every part's pessimistic end stays within the travel (one outside
        it goes no further out: :meth:`Travel.keeps`), with the part (index) that cut it, if one did."""
        k = 0 if axis == "x" else 1
        lo, hi = self.travel.x_m if axis == "x" else self.travel.y_m
        by = None
        for j, p in enumerate(poses):
            room = (hi - p[k]) if direction > 0 else (p[k] - lo)
            fits = math.floor(max(room, 0.0) / high)
            if fits < steps:
                steps, by = fits, j
        return steps, by

    def theta_burst(
        self, poses: list[Pose], i: int, amount: float, anchored: tuple[int, ...] = (), quantity: str = "turn"
    ) -> AxisBurst | Finish | None:
        """A θ burst that turns (or orbits, ``quantity`` "orbit") part ``i`` by up to ``amount`` rad:
        a turn with θ's turning modes, an orbit with those that hold parts near O
        (:meth:`~feeder.pose_response.ResponseModel.orbit_modes`).

        None: no mode moves it by a useful amount here, or not even one step fits the travel;
        Finish ("unreachable"): every useful mode's first step would bring two parts within
        :data:`CLEARANCE_M` (the reason names them).
        """
        direction = 1 if amount > 0 else -1
        need = abs(amount)
        if quantity == "turn" and self.symmetry_rad > 0:  # unambiguous to measure modulo the symmetry
            need = min(need, 0.3 * self.symmetry_rad)
        modes = self.model.modes("theta") if quantity == "turn" else self.model.orbit_modes()
        fine = modes[-1]
        pose = poses[i]
        r = math.hypot(pose[0], pose[1])

        def per_step(mode: str) -> tuple[float, float]:
            s = self.model.turn_step(direction, mode, *pose)
            if quantity == "turn":
                return abs(s.turn_rad), s.turn_std_rad
            return abs(s.orbit_rad), s.orbit_std_rad

        # a turn: USEFUL_TURN of the tolerance per step at least; an orbit USEFUL_ORBIT of it
        if quantity == "turn":
            useful = USEFUL_TURN * self.tolerance_rad
        else:
            useful = USEFUL_ORBIT * self.tolerance_m / max(r, 1e-9)
        fine_step = per_step(fine)[0]
        blocked: tuple[int, int] | None = None
        carried: int | None = None
        for mode in modes:
            step, std = per_step(mode)
            if (mode != fine and step <= fine_step) or step < useful:
                continue
            scale = 1 + 2 * std / step
            steps = self._theta_count(pose, direction, mode, need, scale, mode != fine, quantity)
            steps, crowded, left = self._theta_within(poses, direction, mode, steps, scale, anchored)
            if steps >= 1:
                return AxisBurst("theta", direction, steps, mode)
            blocked = blocked or crowded
            if left is not None and left != i and carried is None:
                carried = left
        verb = "turning" if quantity == "turn" else "orbiting"
        if blocked is None:
            if carried is None:
                return None
            return Finish(
                "unreachable", self._carry_refusal(f"{verb} part {i + 1} further", carried, poses[carried])
            )
        a, b = (k + 1 for k in blocked)
        if i + 1 in (a, b):
            near = f"it within {CLEARANCE_M:.3g} m of part {a + b - i - 1}"
        else:
            near = f"parts {a} and {b} within {CLEARANCE_M:.3g} m of each other"
        return Finish(
            "unreachable",
            f"{verb} part {i + 1} further would bring {near}: parts keep that far apart for the camera "
            "to see them apart",
        )

    def _theta_count(
        self,
        pose: Pose,
        direction: int,
        mode: str,
        need: float,
        scale: float,
        short: bool,
        quantity: str = "turn",
    ) -> int:
        """Steps that turn (orbit) by ``need``: the pessimistic count less one (short), or the nearest.
        An orbit also turns the part: it stops before the pessimistic turn passes 0.3 × the part's
        symmetry, so the burst's turn stays unambiguous to learn from (the camera sees the angle
        modulo the symmetry)."""
        x, y, psi = pose
        done, previous, turned = 0.0, 0.0, 0.0
        for n in range(1, MAX_BURST_STEPS + 1):
            s = self.model.turn_step(direction, mode, x, y, psi)
            step = abs(s.turn_rad if quantity == "turn" else s.orbit_rad)
            if step < 1e-9:
                return 0
            if quantity == "orbit" and self.symmetry_rad > 0:
                turned += abs(s.turn_rad) * scale
                if turned > 0.3 * self.symmetry_rad:
                    return n - 1
            done += step * (scale if short else 1.0)
            x, y, psi = self.model.predict("theta", direction, mode, 1, (x, y, psi))
            if short and done > need:
                return n - 2
            if not short and done >= need:
                return n if done - need < need - previous else n - 1
            previous = done
        return MAX_BURST_STEPS

    def _theta_within(
        self,
        poses: list[Pose],
        direction: int,
        mode: str,
        steps: int,
        scale: float,
        anchored: tuple[int, ...],
    ) -> tuple[int, tuple[int, int] | None, int | None]:
        """``steps`` cut where some part's pessimistic orbit leaves the travel (one outside it: goes
        further out, :meth:`Travel.keeps`), an anchored part moves, or two parts' footprints come
        within :data:`CLEARANCE_M` (closer than they are, when they already are); with the two
        parts (indices) whose clearance cut it, and the part whose travel cut it, if any."""
        if steps < 1:
            return steps, None, None
        floors = self._gap_floors(poses)
        states = list(poses)
        for n in range(1, steps + 1):
            for k, p in enumerate(states):
                nxt = self.model.predict("theta", direction, mode, 1, p, scale)
                if not self.travel.keeps(poses[k], nxt):
                    return n - 1, None, k
                if k in anchored and (
                    math.hypot(nxt[0] - poses[k][0], nxt[1] - poses[k][1]) > 0.2 * self.tolerance_m
                    or abs(nxt[2] - poses[k][2]) > 0.2 * self.tolerance_rad
                ):
                    return n - 1, None, None
                states[k] = nxt
            for (k, j), floor in floors.items():
                if self._gap_below(states[k], states[j], floor):
                    return n - 1, (k, j), None
        return steps, None, None

    def _gap_floors(self, poses: list[Pose]) -> dict[tuple[int, int], float]:
        """Per pair of parts (indices), the gap (m) a θ burst must keep: :data:`CLEARANCE_M`, or
        the gap they have now when less (they may move apart)."""
        return {
            (k, j): CLEARANCE_M if not self._gap_below(a, b, CLEARANCE_M) else gap_m(self.part.patch, a, b)
            for k, a in enumerate(poses)
            for j, b in enumerate(poses)
            if k < j
        }

    def _gap_below(self, a: Pose, b: Pose, floor: float) -> bool:
        """The footprints at ``a`` and ``b`` lie less than ``floor`` (m) apart (circumscribed
        circles first: parts far apart cost one hypot)."""
        if math.hypot(b[0] - a[0], b[1] - a[1]) - 2 * self.part.patch.radius_m >= floor:
            return False
        return gap_m(self.part.patch, a, b) < floor

    def turn_per_step(self, direction: int, pose: Pose) -> float | None:
        """The turn (rad, signed) of one θ step in ``direction`` where this planner turns a part at
        ``pose`` (what a jog of N steps turns by N of): here, by the mode that turns it most, when
        that is :data:`USEFUL_TURN` tolerances or more; else the same at the turning station (of
        the model as learned so far); None: no θ mode turns it anywhere.  (The daemon reported the
        coarse mode's turn until 2026-11-27: 5e-15 rad at O, its dead zone, so a jog there asked
        for the angle the part had and ended "done" with 0 steps, holding that angle.)"""
        useful = USEFUL_TURN * self.tolerance_rad
        turn = self._largest_turn(direction, pose)
        station = None if abs(turn) >= useful else self._station_radius()
        if station is not None:
            turn = self._largest_turn(direction, (station, 0.0, pose[2]))
        return turn if abs(turn) >= useful else None

    def _largest_turn(self, direction: int, pose: Pose) -> float:
        """The signed turn (rad) of one step of the θ mode that turns a part at ``pose`` most."""
        turns = (self.model.turn_step(direction, m, *pose).turn_rad for m in self.model.modes("theta"))
        return max(turns, key=abs, default=0.0)

    def _turns_here(self, pose: Pose, direction: int) -> bool:
        """At the station radius, or where the fine θ mode turns the part by :data:`USEFUL_TURN` … 2
        tolerances per step in ``direction``: beyond the station, or within it where the learned
        model says so for that direction (the station's radius is the one every orientation and
        both directions turn at: a learned −θ step at O of 0.65 mrad with +θ's at 0.37 mrad moved
        it 0.5 mm out, and turns at O went there and back until the move ended "oscillating")."""
        assert self.station_radius_m is not None
        r = math.hypot(pose[0], pose[1])
        if abs(r - self.station_radius_m) <= STATION_BAND_M:
            return True
        fine = abs(self.model.turn_step(direction, self.model.modes("theta")[-1], *pose).turn_rad)
        return USEFUL_TURN * self.tolerance_rad <= fine <= 2 * self.tolerance_rad

    def _station_radius(self) -> float | None:
        """Grid radius nearest O where the fine θ mode turns by ¼ … 1.8 tolerances for every
        orientation (O itself where the drive turns a part in place): the shortest trip out of
        the dead zone, and the smallest orbit (r·Δφ) for the x and y moves to correct.

        From the learned model: a dead zone larger than the seed's moves the station out.
        """
        modes = self.model.modes("theta")
        if not modes:
            return None
        fine = modes[-1]
        corner = max(math.hypot(x, y) for x in self.travel.x_m for y in self.travel.y_m)
        radii = [r for r in self.model.turn[fine].radii_m if 0 <= r < corner]
        ranges = {r: self.model.turn_range(fine, r) for r in radii}
        usable = [r for r in radii if ranges[r][0] >= USEFUL_TURN * self.tolerance_rad]
        within = [r for r in usable if ranges[r][1] <= 1.8 * self.tolerance_rad]
        if within:
            return min(within)
        # the finest turn there is, even if coarser than the tolerance wants
        return min(usable, key=lambda r: ranges[r][1]) if usable else None

    def _station(
        self, poses: list[Pose], i: int, turn: float, then_xy: tuple[float, float]
    ) -> tuple[float, float] | None:
        """The point on the station circle on the way to ``then_xy`` whose turn fits the travel;
        with other parts, carried there alike, also theirs, and the turn keeps every two parts
        :data:`CLEARANCE_M` apart (the station nearest the way had a neighbour turned out of the
        travel, or into the part, 5 of 32 random turns beside a part ~0.6 mm away)."""
        assert self.station_radius_m is not None
        pose = poses[i]
        r_s = self.station_radius_m
        direction = 1 if turn > 0 else -1
        coarse = self.model.modes("theta")[0]
        best: tuple[float, tuple[float, float]] | None = None
        for k in range(STATION_DIRECTIONS):
            a = 2 * math.pi * k / STATION_DIRECTIONS
            start = (r_s * math.cos(a), r_s * math.sin(a), pose[2])
            shift = (start[0] - pose[0], start[1] - pose[1])
            there = [(p[0] + shift[0], p[1] + shift[1], p[2]) for p in poses]
            if not all(self.travel.keeps(p, q) for p, q in zip(poses, there, strict=True)):
                continue
            steps = self._theta_count(start, direction, coarse, abs(turn), 1.0, short=False)
            if self._theta_within(there, direction, coarse, steps, 1.3, ())[0] < steps:
                continue  # the whole turn, 30 % long, must fit, with every part
            end = self.model.predict("theta", direction, coarse, steps, start, 1.3)
            cost = math.hypot(start[0] - pose[0], start[1] - pose[1]) + math.hypot(
                end[0] - then_xy[0], end[1] - then_xy[1]
            )
            if best is None or cost < best[0]:
                best = (cost, (start[0], start[1]))
        return None if best is None else best[1]

    def angle_error(self, pose: Pose, target: Pose) -> float:
        """Signed turn target − pose (rad) modulo the symmetry; 0 for a disc or a NaN (any) target angle."""
        if math.isnan(target[2]):
            return 0.0
        return self._angle_difference(target[2], pose[2])

    def _angle_difference(self, a: float, b: float) -> float:
        if self.symmetry_rad <= 0:
            return 0.0
        return angle_difference(a, b, self.symmetry_rad)
