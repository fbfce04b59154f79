"""Which θ burst turns or orbits a part, and where it turns: pose control's θ (docs/pose-control.md).

Pure: poses in, a θ burst (or the reason there is none) out; no I/O, no clock.
A θ step turns the plate about O, which turns and orbits the parts outside the
dead zone and leaves those inside it stuck (:mod:`feeder.pose_response`).  A
part turns where the fine θ mode turns it by a useful amount, else at a
*station*: a point on the circle (radius :attr:`TurnPlanner.station_radius_m`)
outside the dead zone, which the pose planner's x and y bursts bring it to
(:mod:`feeder.pose_planner`).  A turn steps θ's coarse and fine modes; a pair's
orbit its anchoring ones when the model has them
(:meth:`~feeder.pose_response.ResponseModel.orbit_modes`).  Every θ burst aims
short with a pessimistic (mean + 2σ) step and is cut where a part's path with its largest
plausible step (:meth:`~feeder.pose_gain.GainFilter.bound` at the part's own radius) would
take it out of the travel, or one already outside it further out
(:meth:`~feeder.travel.Travel.keeps`), or its pessimistic path would bring two parts' footprints
within :data:`CLEARANCE_M`.  Lengths in m, angles in rad (modulo the part's symmetry).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from feeder.footprint import gap_m
from feeder.plant.planar import PlanarPart
from feeder.pose import Pose
from feeder.pose_burst import MAX_BURST_STEPS, AxisBurst, Finish, carry_refusal
from feeder.pose_gain import SEED_STD
from feeder.pose_response import ResponseModel
from feeder.travel import Travel
from feeder.vision.model import angle_difference

STATION_BAND_M = 40e-6
"""A part within this of its turning station's radius turns there."""
STATION_DIRECTIONS = 36
USEFUL_TURN = 0.25
"""A θ mode turns a part (a turn burst steps it, the turning station is where its fine mode does)
when one step turns the part by at least this fraction of ``tolerance_rad``."""
USEFUL_ORBIT = 0.02
"""An orbit step (two parts placed relative to each other, to half the tolerance) is worth a θ
burst when it moves the part by at least this fraction of ``tolerance_m``."""
CLEARANCE_M = 40e-6
"""θ bursts and targets keep every two parts' footprints at least this far apart (m), or as far
as they are when already closer: the camera must see them apart.  Its blob search works on the
image shrunk 2–4× and its edge fits sample profiles reaching 10 px beyond each side
(:mod:`feeder.vision.locate`, :mod:`feeder.vision.edges`): 27 µm at the cameras' 2.7 µm/px, or a
neighbour merges the blobs ("overlapped or touching parts") or bends the fitted edge.  The rest
(13 µm) covers what the pessimistic prediction (mean + 2σ per step) misses and the last step
before the cut (a coarse θ step moves a 300 µm part's corner by a few µm)."""


@dataclass(eq=False)
class TurnPlanner:
    """θ bursts for part ``i`` among ``poses``, and where a part turns (part indices count from 0).

    model: per-step response (learned online by the pose planner).  travel: the centres' allowed
    range.  part: the geometry (footprint, for the clearance).  tolerance_m, tolerance_rad: the
    pose planner's; symmetry_rad: the period angles compare modulo (0: any angle).
    station_radius_m: the turning station's radius, as of :meth:`update_station` (None: no θ mode
    turns the part anywhere within the travel).
    """

    model: ResponseModel
    travel: Travel
    part: PlanarPart
    tolerance_m: float
    tolerance_rad: float
    symmetry_rad: float
    station_radius_m: float | None = field(init=False)

    def __post_init__(self) -> None:
        self.station_radius_m = self._station_radius()

    def update_station(self) -> float | None:
        """The station radius from the model as learned so far, kept in :attr:`station_radius_m`."""
        self.station_radius_m = self._station_radius()
        return self.station_radius_m

    def theta_burst(
        self,
        poses: list[Pose],
        i: int,
        amount: float,
        anchored: tuple[int, ...] = (),
        quantity: str = "turn",
        anchored_angles: bool = True,
    ) -> AxisBurst | Finish | None:
        """A θ burst that turns (or orbits, ``quantity`` "orbit") part ``i`` by up to ``amount`` rad:
        a turn with θ's turning modes, an orbit with those that hold parts near O
        (:meth:`~feeder.pose_response.ResponseModel.orbit_modes`).  ``anchored`` parts stay put
        (and keep their angle unless ``anchored_angles`` is False: held at any angle).

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
            steps, crowded, left = self._theta_within(
                poses, direction, mode, steps, scale, anchored, anchored_angles
            )
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
                "unreachable",
                carry_refusal(self.travel, f"{verb} part {i + 1} further", carried, poses[carried]),
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
        anchored_angles: bool = True,
    ) -> tuple[int, tuple[int, int] | None, int | None]:
        """``steps`` cut where some part's orbit with its largest plausible step (at least the
        pessimistic one; ``predict``'s ``bound``, each part at its own radius) leaves the travel
        (one outside it: goes further out, :meth:`Travel.keeps`), an anchored part moves, or two
        parts' footprints come within :data:`CLEARANCE_M` on their pessimistic paths (closer than
        they are, when they already are); with the two parts (indices) whose clearance cut it,
        and the part whose travel cut it, if any.  (Until 2026-11-29 the travel took the moving
        part's relative spread for every part: one whose radius no burst had informed orbited
        with the learned part's few per cent.)"""
        if steps < 1:
            return steps, None, None
        floors = self._gap_floors(poses)
        states = list(poses)
        far = list(poses)
        # a θ step orbits a part about O: one whose radius cannot reach the travel's edge nearest
        # O over the burst (radial drift at its largest) stays within it, however far it orbits
        inner = min(-self.travel.x_m[0], self.travel.x_m[1], -self.travel.y_m[0], self.travel.y_m[1])
        drift = steps * max(scale, 1 + 2 * SEED_STD) * self.model.radial_reach_m(mode)
        watched = [math.hypot(p[0], p[1]) + drift >= inner for p in poses]
        for n in range(1, steps + 1):
            for k, p in enumerate(states):
                nxt = self.model.predict("theta", direction, mode, 1, p, scale)
                if watched[k]:
                    far[k] = self.model.predict("theta", direction, mode, 1, far[k], scale, bound=True)
                if not (self.travel.keeps(poses[k], nxt) and self.travel.keeps(poses[k], far[k])):
                    return n - 1, None, k
                if k in anchored and (
                    math.hypot(nxt[0] - poses[k][0], nxt[1] - poses[k][1]) > 0.2 * self.tolerance_m
                    or (anchored_angles and abs(nxt[2] - poses[k][2]) > 0.2 * self.tolerance_rad)
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

    def turns_here(self, pose: Pose, direction: int) -> bool:
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

    def station(
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
        return self.angle_difference(target[2], pose[2])

    def angle_difference(self, a: float, b: float) -> float:
        if self.symmetry_rad <= 0:
            return 0.0
        return angle_difference(a, b, self.symmetry_rad)
