"""Pose planner in closed loop against the planar plant (PlanarStickSlip), not against its own model."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from feeder.parts import Part
from feeder.plant.planar import PlanarPart, PlanarStickSlip
from feeder.plant.plate_motion import Segment
from feeder.plant.stick_slip import Friction
from feeder.pose import Pose, pose_error
from feeder.pose_burst import AxisBurst, Finish
from feeder.pose_gain import GainFilter
from feeder.pose_pair import _anchor, _length_leg, _length_orbit, anchor_radius_m, next_pair_burst
from feeder.pose_planner import PROBE_FRACTION, PosePlanner
from feeder.pose_response import ANCHOR_MODES, AxisMode, ResponseModel, TurnTable, seed_response
from feeder.travel import Travel

F_HZ, FLYBACK_S = 100.0, 3.5e-4
MODES = (
    AxisMode("x", "coarse", 14e-6, F_HZ, FLYBACK_S),
    AxisMode("x", "fine", 11e-6, F_HZ, FLYBACK_S),
    AxisMode("y", "coarse", 14e-6, F_HZ, FLYBACK_S),
    AxisMode("y", "fine", 11e-6, F_HZ, FLYBACK_S),
    AxisMode("theta", "coarse", 14e-3, F_HZ, FLYBACK_S),
    AxisMode("theta", "fine", 7e-3, F_HZ, FLYBACK_S),
)
TURNING = (  # the daemon's θ at 1 kHz (ideal_modes): a part turns anywhere, O included
    AxisMode("theta", "coarse", 9.6e-3, 1000.0, 2.0e-4),
    AxisMode("theta", "fine", 1.25e-3, 1000.0, 3.15e-5),
)
BOTH = (  # several parts on a CANopen drive: MODES' θ anchors (dead zone ~0.5 mm), TURNING turns
    *(m for m in MODES if m.axis != "theta"),
    *TURNING,
    *(AxisMode("theta", a, m.stroke, F_HZ, FLYBACK_S) for a, m in zip(ANCHOR_MODES, MODES[4:], strict=True)),
)
PART = PlanarPart.from_part(Part.parse("500x300x50"), Friction(105.25, 0.8))
RADII = (0.0, 0.5e-3, 1.0e-3, 1.25e-3, 1.5e-3, 1.75e-3, 2.0e-3, 2.5e-3, 3.0e-3)
TRAVEL = Travel((-1.8e-3, 1.8e-3), (-1.8e-3, 1.8e-3))
TOL_M, TOL_RAD = 1e-6, math.radians(0.1)


class World:
    """The plant: bursts of ideal sawtooth periods, entered and left by gentle ramps (no corner)."""

    def __init__(
        self,
        poses: list[tuple[float, float, float]],
        part: PlanarPart = PART,
        modes: tuple[AxisMode, ...] = MODES,
    ) -> None:
        parts = [PlanarPart(part.patch, part.mass_kg, part.inertia_kg_m2, part.friction, p) for p in poses]
        self.solver = PlanarStickSlip(parts)
        self.modes = modes
        self.steps = 0
        self.bursts: list[AxisBurst] = []

    def burst(self, b: AxisBurst) -> None:
        mode = next(m for m in self.modes if m.axis == b.axis and m.mode == b.mode)
        motion = mode.motion(b.direction, b.steps)
        v = motion.initial_velocity
        ramp = 2e-3
        acc = (v[0] / ramp, v[1] / ramp, v[2] / ramp)
        segments = (
            Segment(ramp, (0.0, 0.0, 0.0), acc),
            *motion.segments,
            Segment(ramp, v, (-acc[0], -acc[1], -acc[2])),
        )
        self.solver.advance(segments, len(segments))
        self.steps += b.steps
        self.bursts.append(b)

    def poses(self) -> list[tuple[float, float, float]]:
        return [(float(p[0]), float(p[1]), float(p[2])) for p in self.solver.poses()]


class RestingWorld(World):
    """The plate rests where each axis' last burst leaves it, as an ANC300's output does: at 0 V
    after forward steps, at the top of its table (the plate a stroke on) after backward ones;
    grounding takes every axis to 0 V and the next burst's enable back to its level.  The
    parts, stuck to the plate, go along; they are seen in the lab's (the camera's) frame."""

    def __init__(self, poses: list[tuple[float, float, float]], modes: tuple[AxisMode, ...]) -> None:
        super().__init__(poses, modes=modes)
        self.driven = {"x": 0.0, "y": 0.0, "theta": 0.0}  # the plate's pose at each axis' level
        self.grounded = True

    def burst(self, b: AxisBurst) -> None:
        mode = next(m for m in self.modes if m.axis == b.axis and m.mode == b.mode)
        self.driven[b.axis] = 0.0 if b.direction > 0 else mode.stroke
        self.grounded = False
        super().burst(b)

    def ground(self) -> None:
        self.grounded = True

    def poses(self) -> list[tuple[float, float, float]]:
        x, y, theta = (0.0, 0.0, 0.0) if self.grounded else tuple(self.driven.values())
        c, s = math.cos(theta), math.sin(theta)
        return [(c * p[0] - s * p[1] + x, s * p[0] + c * p[1] + y, p[2] + theta) for p in super().poses()]


def run(planner: PosePlanner, world: World, targets: dict[int, tuple[float, float, float]]) -> Finish:
    for _ in range(200):
        before = world.poses()
        nxt = planner.next_burst(before, targets)
        if isinstance(nxt, Finish):
            return nxt
        world.burst(nxt)
        planner.learn(nxt, before, world.poses())
    raise AssertionError("no verdict after 200 bursts")


def place(planner: PosePlanner, world: World, targets: dict[int, tuple[float, float, float]]) -> None:
    """Run the planner to its verdict: done, with every part's centre within the tolerance."""
    verdict = run(planner, world, targets)
    assert verdict.status == "done", verdict
    for pid, target in targets.items():
        pose = world.poses()[pid - 1]
        assert math.hypot(pose[0] - target[0], pose[1] - target[1]) <= TOL_M


@pytest.fixture(scope="module")
def model_seed() -> ResponseModel:
    return seed_response(PART, MODES, RADII)


def fresh(scale: float = 1.0) -> ResponseModel:
    """A new model (gains 1) on the cached seed tables; x/y seeds multiplied by ``scale``."""
    seeded = seed_response(PART, MODES, RADII)
    return ResponseModel({k: v * scale for k, v in seeded.translation.items()}, seeded.turn)


def test_five_random_targets_within_tolerance(model_seed: ResponseModel) -> None:
    rng = random.Random(16)
    planner = PosePlanner(fresh(), TRAVEL, PART, TOL_M, TOL_RAD)
    world = World([(0.3e-3, -0.2e-3, 0.1)])
    targets = [
        (0.05e-3, -0.1e-3, 0.1 + math.radians(35)),  # a turn of 35° near O: out, turn, back
        (rng.uniform(-1.2e-3, 1.2e-3), rng.uniform(-1.2e-3, 1.2e-3), rng.uniform(0, math.pi)),
    ]
    targets += [
        (rng.uniform(-0.8e-3, 0.8e-3), rng.uniform(-0.8e-3, 0.8e-3), rng.uniform(0, 0.5)) for _ in range(3)
    ]
    for target in targets:
        verdict = run(planner, world, {1: target})
        assert verdict.status == "done", verdict
        error_m, error_rad = pose_error(world.poses()[0], target, math.pi)
        assert error_m <= TOL_M and error_rad <= TOL_RAD, (target, world.poses())
        assert TRAVEL.contains(*world.poses()[0][:2])


def test_turn_near_o_moves_out_and_back(model_seed: ResponseModel) -> None:
    planner = PosePlanner(fresh(), TRAVEL, PART, TOL_M, TOL_RAD)
    world = World([(0.0, 0.0, 0.0)])
    first = planner.next_burst(world.poses(), {1: (0.0, 0.0, math.radians(30))})
    assert isinstance(first, AxisBurst) and first.axis in ("x", "y")  # no θ step can turn it at O
    world.burst(first)
    verdict = run(planner, world, {1: (0.0, 0.0, math.radians(30))})
    assert verdict.status == "done"
    error_m, error_rad = pose_error(world.poses()[0], (0.0, 0.0, math.radians(30)), math.pi)
    assert error_m <= TOL_M and error_rad <= TOL_RAD


def test_targets_outside_the_travel_refused(model_seed: ResponseModel) -> None:
    planner = PosePlanner(fresh(), TRAVEL, PART)
    poses = [(0.0, 0.0, 0.0)]
    for target in [(2e-3, 0.0, 0.0), (0.0, -1.9e-3, 0.0)]:
        reason = planner.check({1: target}, poses)
        assert reason is not None and "outside the travel" in reason
        verdict = planner.next_burst(poses, {1: target})
        assert verdict == Finish("unreachable", reason)
    assert planner.check({1: (1.7e-3, -1.7e-3, 1.0)}, poses) is None


def test_bursts_never_leave_the_travel(model_seed: ResponseModel) -> None:
    planner = PosePlanner(fresh(), TRAVEL, PART)
    poses = [(1.79e-3, 0.0, 0.0)]
    burst = planner.next_burst(poses, {1: (1.8e-3, 0.0, 0.0)})
    assert isinstance(burst, AxisBurst) and burst.mode == "fine"  # no coarse step fits the 10 µm left
    step, std = planner.model.step_m("x", 1, "fine")
    assert burst.steps * (step + 2 * std) <= 10e-6
    assert isinstance(planner.next_burst([(1.8e-3, 0.0, 0.0)], {1: (1.8e-3, -0.5e-3, 0.0)}), AxisBurst)
    # the other way: nothing fits beyond the edge, so the planner says so instead of stepping
    stuck = planner.next_burst([(1.8e-3, 0.0, 0.0)], {1: (1.8e-3 - 0.4e-6, 0.0, 0.0)})
    assert stuck == Finish("done", "every part within tolerance")


@pytest.mark.parametrize(
    ("part_1", "part_2", "turn"),
    [  # old ends: "turning part 1 further would bring it within 4e-05 m of part 2" (0.6 mm apart),
        ((0.11e-3, -1.176e-3, 0.216), (-0.470e-3, -1.015e-3, -0.321), -0.490),
        # ... "turning part 1 further would carry part 2 ... out of the travel"
        ((-0.736e-3, -0.357e-3, -0.055), (-1.270e-3, -0.942e-3, -0.495), -0.684),
        # ... "moving part 1 further in +x would carry part 2 ... out of the travel" (to the station)
        ((0.517e-3, -0.020e-3, -0.042), (1.030e-3, -0.124e-3, -0.135), -0.306),
    ],
)
def test_a_turn_beside_another_part_picks_a_station_with_room_for_both(
    model_seed: ResponseModel, part_1: Pose, part_2: Pose, turn: float
) -> None:
    """The turning station was the one nearest the way, whatever the other part: carried there
    and turned along, it left the travel or came within the clearance of the turning part, and
    the move ended "unreachable" (5 of 32 random turns beside a part 0.5–0.8 mm away; 31 of 101
    before this, 3 now)."""
    planner = PosePlanner(fresh(), TRAVEL, PART, TOL_M, TOL_RAD)
    target = (part_1[0], part_1[1], part_1[2] + turn)
    assert planner.check({1: target}, [part_1, part_2]) is None
    world = World([part_1, part_2])
    verdict = run(planner, world, {1: target})
    assert verdict.status == "done", verdict
    error_m, error_rad = pose_error(world.poses()[0], target, math.pi)
    assert error_m <= TOL_M and error_rad <= TOL_RAD
    other = world.poses()[1]
    assert TRAVEL.contains(other[0], other[1])


def test_learning_converges_when_the_step_is_30_percent_off(model_seed: ResponseModel) -> None:
    model = fresh(scale=1 / 1.3)  # the seed believes the steps are 30 % shorter than they are
    planner = PosePlanner(model, TRAVEL, PART, TOL_M, TOL_RAD)
    world = World([(-1.0e-3, -1.0e-3, 0.0)])
    for target in [(1.0e-3, 1.0e-3, 0.0), (-0.6e-3, 0.4e-3, 0.0)]:
        verdict = run(planner, world, {1: target})
        assert verdict.status == "done"
        assert pose_error(world.poses()[0], target, math.pi)[0] <= TOL_M
    for axis in ("x", "y"):
        for direction in (1, -1):
            learned, _ = model.step_m(axis, direction, "coarse")
            assert learned == pytest.approx(model_seed.translation[(axis, "coarse")], rel=0.05)


def test_a_device_six_times_its_seed_is_probed_and_never_driven_out_of_the_travel() -> None:
    """A fresh state on a real device whose step is 6× the physics' seed: the whole-way first
    burst (aimed short by the prior's 2σ) carried the part 2.75× the way, 1.4 mm past a target
    1.6 mm off, out of the ±1.8 mm travel and the camera's view.  Unlearned steps are probed
    (:data:`PROBE_FRACTION` of the way), and the move ends placed with the step learned."""
    model = fresh(scale=1 / 6)
    planner = PosePlanner(model, TRAVEL, PART, TOL_M, TOL_RAD)
    world = World([(-1.0e-3, 0.0, 0.0)])
    target = (0.6e-3, 0.0, 0.0)
    first = planner.next_burst(world.poses(), {1: target})
    assert isinstance(first, AxisBurst) and first.axis == "x" and first.mode == "coarse"
    seed, _ = model.step_m("x", 1, "coarse")
    assert first.steps * seed <= PROBE_FRACTION * 1.6e-3 * (1 + 1e-9)
    xs = []
    for _ in range(200):
        before = world.poses()
        nxt = planner.next_burst(before, {1: target})
        if isinstance(nxt, Finish):
            break
        world.burst(nxt)
        planner.learn(nxt, before, world.poses())
        xs.append(world.poses()[0][0])
    assert nxt == Finish("done", "every part within tolerance")
    assert max(xs) <= target[0] + 0.1e-3 and TRAVEL.contains(max(xs), 0.0)  # never far past the target
    assert model.step_m("x", 1, "coarse")[0] == pytest.approx(6 * seed, rel=0.1)


def test_two_parts_reach_their_own_targets(model_seed: ResponseModel) -> None:
    planner = PosePlanner(fresh(), TRAVEL, PART, TOL_M, TOL_RAD)
    world = World([(0.0, 0.0, 0.0), (1.5e-3, 0.0, 0.0)])
    targets = {1: (0.2e-3, -0.3e-3, 0.0), 2: (0.4e-3, 1.5e-3, math.nan)}
    assert planner.check(targets, world.poses()) is None
    place(planner, world, targets)
    assert pose_error(world.poses()[0], targets[1], math.pi)[1] <= TOL_RAD  # the anchored part kept its angle


def test_unreachable_pairs_refused_with_the_reason(model_seed: ResponseModel) -> None:
    planner = PosePlanner(fresh(), TRAVEL, PART, TOL_M, TOL_RAD)
    poses = [(0.0, 0.0, 0.0), (1.5e-3, 0.0, 0.0)]
    far = planner.check({1: (0.0, 0.0, 0.0), 2: (0.9e-3, 0.0, math.nan)}, poses)
    assert far is not None and "cannot change that much" in far  # 0.6 mm closer: beyond the dead zone
    angled = planner.check({1: (0.0, 0.0, 0.0), 2: (0.0, 1.5e-3, 0.5)}, poses)
    assert angled is not None and "place it without an angle, or let it go: feeder release --part 2" in angled
    overlap = planner.check({1: (0.0, 0.0, 0.0), 2: (0.2e-3, 0.0, math.nan)}, poses)
    assert overlap is not None and "overlap" in overlap
    verdict = planner.next_burst(poses, {1: (0.0, 0.0, 0.0), 2: (0.9e-3, 0.0, math.nan)})
    assert isinstance(verdict, Finish) and verdict.status == "unreachable"


def test_a_pair_off_by_less_than_the_tolerance_is_done_or_translated_not_refused(
    model_seed: ResponseModel,
) -> None:
    """Parts as far apart as their targets within the tolerance, though not within half of it
    (no orbit corrects that: its anchor runs off to ~0.3 m): done when each is within the
    tolerance, else translated until each is (the plane HIL test once ended such a move
    "unreachable" 0.55 µm off)."""
    planner = PosePlanner(fresh(), TRAVEL, PART, TOL_M, TOL_RAD)
    targets = {1: (0.0, 0.0, 0.0), 2: (1.5e-3, 0.0, math.nan)}
    both_within = [(0.3e-6, 0.0, 0.0), (1.5e-3 - 0.3e-6, 0.0, 0.0)]  # 0.6 µm apart from d_t
    assert planner.check(targets, both_within) is None
    assert planner.next_burst(both_within, targets) == Finish("done", "every part within tolerance")
    one_out = [(1.2e-6, 0.0, 0.0), (1.5e-3 + 0.6e-6, 0.0, 0.0)]  # part 1 1.2 µm off, 0.6 µm relative
    assert planner.check(targets, one_out) is None
    world = World(one_out)
    place(planner, world, targets)
    assert world.steps <= 3  # a fine step or so in x, no orbit


def test_a_pair_whose_orbit_cannot_run_is_translated_when_that_will_do(model_seed: ResponseModel) -> None:
    """Parts 0.9 mm apart, off each other by 1.2–1.9 µm: B cannot orbit there (the test modes'
    dead zone), so translating both is all there is; a relative error under twice the tolerance
    may leave each within it.  The planner went to the anchor first, found B's orbit impossible
    and ended "unreachable" 260 µm off both targets."""
    targets = {1: (0.0, 0.0, 0.0), 2: (0.9e-3, 0.0, math.nan)}
    for rel, placed in ((1.2e-6, True), (1.5e-6, False), (1.9e-6, False)):
        planner = PosePlanner(fresh(), TRAVEL, PART, TOL_M, TOL_RAD)
        world = World([(40e-6, 30e-6, 0.0), (0.9e-3 + 40e-6 + 0.6 * rel, 30e-6 + 0.8 * rel, 0.0)])
        verdict = run(planner, world, targets)
        errors = [
            math.hypot(p[0] - t[0], p[1] - t[1]) for p, t in zip(world.poses(), targets.values(), strict=True)
        ]
        assert not [b for b in world.bursts if b.axis == "theta"] and world.steps < 40
        if verdict.status == "done":
            assert max(errors) <= TOL_M, (verdict, errors)
        else:  # each about half of it off, on 1.08 µm fine steps: said so, next to the targets
            assert not placed and verdict.status == "unreachable" and "fine steps cannot" in verdict.reason
            assert max(errors) <= 2 * TOL_M


def test_a_pair_whose_orbit_fails_at_the_anchor_ends_back_about_its_targets(
    model_seed: ResponseModel,
) -> None:
    """Parts 0.9 mm apart to be 10 µm further apart: A went ~0.13 mm to the length leg's anchor,
    where B's orbit (the test modes' dead zone) proved impossible, and the move ended there,
    134 and 140 µm off the targets (on the CAN plane 140–470 µm).  Now both are translated
    back about their targets before the move ends "unreachable" with the reason.  (5 µm further
    apart is placed since backward orbits aim past their end, :data:`~feeder.pose_pair.PAST`.)"""
    planner = PosePlanner(fresh(), TRAVEL, PART, TOL_M, TOL_RAD)
    targets = {1: (0.0, 0.0, 0.0), 2: (0.9e-3 + 10e-6, 0.0, math.nan)}
    world = World([(0.0, 0.0, 0.0), (0.9e-3, 0.0, 0.0)])
    verdict = run(planner, world, targets)
    assert verdict.status == "unreachable" and "cannot orbit" in verdict.reason
    errors = [
        math.hypot(p[0] - t[0], p[1] - t[1]) for p, t in zip(world.poses(), targets.values(), strict=True)
    ]
    (a, b), (ta, tb) = world.poses(), targets.values()
    rel = math.hypot(b[0] - a[0] - (tb[0] - ta[0]), b[1] - a[1] - (tb[1] - ta[1]))  # the leg turned d
    assert max(errors) <= rel / 2 + 2 * TOL_M and max(errors) < 10e-6, (errors, rel)


@pytest.mark.parametrize("radial_m", [1.5e-6, -2.02e-6, 40e-6, 0.3e-3])
def test_a_pair_off_along_the_line_joining_them_is_placed_by_a_length_leg(
    model_seed: ResponseModel, radial_m: float
) -> None:
    """d off d_t along d itself: the plan's anchor lies ~|d| from O, far beyond the dead zone, so
    one orbit cannot correct it (refused, or "unreachable" after an orbit left 2.02 µm of it, as
    in 2 of 5 CI runs of the CAN pair HIL test until 2026-11-27).  A length leg (A held
    LEG_REACH·r_a from O, the line joining them turned) and the plan's orbit back place both."""
    planner = PosePlanner(fresh(), TRAVEL, PART, TOL_M, TOL_RAD)
    targets = {1: (0.0, 0.0, 0.0), 2: (1.5e-3, 0.0, math.nan)}
    poses = [(1.2e-6, 0.0, 0.0), (1.5e-3 + 1.2e-6 + radial_m, 0.0, 0.0)]
    assert planner.check(targets, poses) is None
    world = World(poses)
    place(planner, world, targets)
    orbits = {b.direction for b in world.bursts if b.axis == "theta"}
    assert orbits == {1, -1}  # out along the leg, back along the plan


def test_a_length_leg_keeps_its_anchor_where_it_said_and_its_orbit_sets_the_distance() -> None:
    """The geometry against closed forms: d_m as long as d_t with the anchor (drift aside)
    ``reach`` from O; B orbited by :func:`_length_orbit` ends ``length`` from A; and a change
    of more than 2·reach has no leg."""
    rng = random.Random(7)
    for _ in range(200):
        n = rng.uniform(0.8e-3, 2e-3)
        angle = rng.uniform(-math.pi, math.pi)
        d = (n * math.cos(angle), n * math.sin(angle))
        turn, grow = rng.uniform(-0.1, 0.1), rng.uniform(-0.2e-3, 0.2e-3)
        d_t = ((n + grow) * math.cos(angle + turn), (n + grow) * math.sin(angle + turn))
        reach = rng.uniform(0.11e-3, 0.4e-3)
        d_m = _length_leg(d, d_t, reach)
        assert d_m is not None
        assert math.hypot(*d_m) == pytest.approx(n + grow, rel=1e-12)
        assert math.hypot(*_anchor(d, d_m, 0.0)) == pytest.approx(reach, rel=1e-6)
        a = (rng.uniform(-0.3e-3, 0.3e-3), rng.uniform(-0.3e-3, 0.3e-3), 0.0)
        b = (a[0] + d[0], a[1] + d[1], 0.0)
        phi = _length_orbit(a, b, n + grow)
        if phi is not None:
            c, s = math.cos(phi), math.sin(phi)
            end = (c * b[0] - s * b[1], s * b[0] + c * b[1])
            assert math.hypot(end[0] - a[0], end[1] - a[1]) == pytest.approx(n + grow, rel=1e-9)
        else:  # A held there cannot bring B that far or near: |d| stays within | |a + d| ± |a| |
            r_a, r_b = math.hypot(a[0], a[1]), math.hypot(b[0], b[1])
            assert not abs(r_b - r_a) <= n + grow <= r_b + r_a
    assert _length_leg((1.5e-3, 0.0), (1.0e-3, 0.0), 0.24e-3) is None  # 0.5 mm > 2 × 0.24 mm
    assert _length_leg((1.5e-3, 0.0), (1.0e-3, 0.0), 0.26e-3) is not None


def test_with_both_theta_families_a_part_turns_among_others_and_a_pair_orbits_anchored(
    model_seed: ResponseModel,
) -> None:
    """Several parts on a CANopen drive: θ's coarse and fine turn one part (the other carried
    along, kept apart), the anchoring family alone orbits a pair, whose dead zone the turning
    modes (which turn parts at O) do not shrink."""
    planner = PosePlanner(seed_response(PART, BOTH, RADII), TRAVEL, PART, TOL_M, TOL_RAD)
    assert planner.model.modes("theta") == ["coarse", "fine"]
    assert planner.model.orbit_modes() == list(ANCHOR_MODES)
    anchored_only = PosePlanner(fresh(), TRAVEL, PART, TOL_M, TOL_RAD)  # MODES' θ: the old planning
    assert anchor_radius_m(planner) == anchor_radius_m(anchored_only) > 0.4e-3
    assert planner.turns.station_radius_m == 0.0  # the 1 kHz modes turn a part in place

    world = World([(0.3e-3, -0.2e-3, 0.1), (-0.9e-3, 0.9e-3, 0.0)], modes=BOTH)
    target = (0.3e-3, -0.2e-3, 0.1 + math.radians(35))
    assert planner.check({1: target}, world.poses()) is None
    verdict = run(planner, world, {1: target})
    assert verdict.status == "done", verdict
    error_m, error_rad = pose_error(world.poses()[0], target, math.pi)
    assert error_m <= TOL_M and error_rad <= TOL_RAD
    turns = [b for b in world.bursts if b.axis == "theta"]
    assert turns and {b.mode for b in turns} <= {"coarse", "fine"}

    world = World([(0.0, 0.0, 0.0), (1.5e-3, 0.0, 0.0)], modes=BOTH)
    targets = {1: (0.2e-3, -0.3e-3, 0.0), 2: (0.4e-3, 1.5e-3, math.nan)}
    assert planner.check(targets, world.poses()) is None
    place(planner, world, targets)
    orbits = [b for b in world.bursts if b.axis == "theta"]
    assert orbits and {b.mode for b in orbits} <= set(ANCHOR_MODES)


@pytest.mark.parametrize("side", [1, -1])
def test_a_pair_ends_on_a_forward_orbit_so_that_grounding_theta_leaves_it_placed(
    model_seed: ResponseModel, side: int
) -> None:
    """After backward θ steps the plate rests turned by the stroke; the done check grounds it
    (docs/daemon.md), turning both parts about O, which no translation undoes.  A CANopen pair
    1.1 mm apart whose orbit ran backward read 2.3–4.3 µm off after each of its 4 grounds and
    ended "unreachable" (5 of 5 runs).  A backward orbit now aims past its end, so the pair's
    last θ burst is forward and the ground leaves the pair where it was placed, on either side."""
    planner = PosePlanner(seed_response(PART, BOTH, RADII), TRAVEL, PART, TOL_M, TOL_RAD)
    world = RestingWorld([(0.0, 0.0, 0.0), (1.5e-3, 0.0, 0.0)], BOTH)
    targets = {1: (0.2e-3, -side * 0.3e-3, 0.0), 2: (0.4e-3, side * 1.5e-3, math.nan)}
    assert planner.check(targets, world.poses()) is None
    verdict = run(planner, world, targets)
    assert verdict.status == "done", verdict
    orbits = [b for b in world.bursts if b.axis == "theta"]
    assert orbits[0].direction == side and orbits[-1].direction == 1
    world.ground()
    for pid, target in targets.items():
        pose = world.poses()[pid - 1]
        assert math.hypot(pose[0] - target[0], pose[1] - target[1]) <= TOL_M, (pid, pose, target)


DEAD_ZONE_TURN_RAD = 30e-6


class TurningDeadZone(ResponseModel):
    """The seed, but a θ step also turns a part in the dead zone (by 6.5 µrad in the CAN plane's
    learned response at 0.42 mm from O, the plant's ringing; the seed's turn there is ~0)."""

    def predict(
        self,
        axis: str,
        direction: int,
        mode: str,
        steps: int,
        pose: tuple[float, float, float],
        scale: float = 1.0,
        bound: bool = False,
    ) -> tuple[float, float, float]:
        x, y, psi = super().predict(axis, direction, mode, steps, pose, scale, bound)
        if axis == "theta" and math.hypot(pose[0], pose[1]) < 0.5e-3:
            psi += direction * steps * DEAD_ZONE_TURN_RAD
        return x, y, psi


def test_a_pair_whose_anchor_is_held_at_any_angle_orbits_in_bursts_its_turn_does_not_cut() -> None:
    """A's turn cut each orbit burst at 0.2 × the angle tolerance (0.02°) even when A was held at
    any angle; every burst then costs A's re-anchoring (on the CAN plane 117–131 bursts, 160–170 s
    for a pair).  Held at an angle, A's turn still cuts them."""
    seed = seed_response(PART, BOTH, RADII)
    planner = PosePlanner(TurningDeadZone(seed.translation, seed.turn), TRAVEL, PART, TOL_M, TOL_RAD)
    poses = [(0.45e-3, 0.0, 0.0), (-1.2e-3, 0.3e-3, 0.0)]
    c, s = math.cos(-0.3), math.sin(-0.3)  # B 0.3 rad on, backward, as far from O: from where A is
    end = (c * poses[1][0] - s * poses[1][1], s * poses[1][0] + c * poses[1][1])
    bursts = {}
    for angle in (math.nan, 0.0):
        targets = {1: (0.45e-3, 0.0, angle), 2: (*end, math.nan)}
        bursts[angle == 0.0] = next_pair_burst(planner, poses, targets)
    free, held = bursts[False], bursts[True]
    assert isinstance(free, AxisBurst) and isinstance(held, AxisBurst)
    assert free.axis == held.axis == "theta" and free.direction == held.direction == -1
    assert held.steps <= 0.2 * TOL_RAD / DEAD_ZONE_TURN_RAD < free.steps


def test_learned_gains_survive_a_restart_and_mismatched_ones_are_left_at_the_seed() -> None:
    from feeder.pose_response import ResponseModel

    seeds = {("x", "coarse"): 2e-6, ("y", "coarse"): 2e-6}
    model = ResponseModel(seeds, {})
    for _ in range(5):  # the true x step is 30 % longer than the seed
        model.learn("x", 1, "coarse", 100, (0.0, 0.0, 0.0), (260e-6, 0.0, 0.0))
    learned = model.step_m("x", 1, "coarse")
    assert learned[0] == pytest.approx(2.6e-6, rel=0.02)
    fresh = ResponseModel(seeds, {})
    saved = model.estimates_json()
    saved["y/+/coarse/step"] = {"radii_m": [1.0], "gain": [9.0], "gain_std": [0.1], "bursts": 3}  # other bins
    assert fresh.restore(saved) == len(seeds) * 2 - 1
    assert fresh.step_m("x", 1, "coarse") == pytest.approx(learned)
    assert fresh.step_m("y", 1, "coarse")[0] == pytest.approx(2e-6)  # left at the seed


def test_gain_filter_at_is_the_weighted_gain_and_its_std() -> None:
    """``at`` (scalars, two bins) equals the full weights' ``w·g`` and ``sqrt(wᵀ C w)``, inside the
    bins, on them and beyond their ends, after updates that correlate the bins."""
    gains = GainFilter([0.0, 0.7e-3, 1.5e-3, 3e-3])
    for r, predicted, measured in ((0.2e-3, 1e-3, 1.3e-3), (2.1e-3, 2e-3, 1.5e-3), (3.5e-3, 1e-3, 0.9e-3)):
        gains.update(r, predicted, measured, 1e-8)
    for r in np.linspace(-1e-3, 4e-3, 51):
        w = gains.weights(float(r))
        gain, std = gains.at(float(r))
        assert gain == pytest.approx(float(w @ gains.gain), rel=1e-13)
        assert std == pytest.approx(math.sqrt(float(w @ gains.covariance @ w)), rel=1e-12)
    single = GainFilter([0.0])
    single.update(0.0, 1e-3, 1.2e-3, 1e-8)
    assert single.at(5e-3) == pytest.approx((float(single.gain[0]), math.sqrt(single.covariance[0, 0])))


def test_a_burst_far_off_its_prediction_is_not_learned_from_but_a_real_change_is(
    model_seed: ResponseModel, caplog: pytest.LogCaptureFixture
) -> None:
    """Seen on a loaded machine: frames lagging behind made a 2-step fine θ burst "orbit" a part
    0.24 rad (another burst's motion) and set gains of 228; such a reading is not folded in."""
    gains = GainFilter([0.0, 0.7e-3, 1.5e-3])
    assert not gains.update(0.5e-3, 2e-3, 0.24, 2 * (0.1e-6 / 0.5e-3) ** 2)
    assert gains.gain.tolist() == [1.0, 1.0, 1.0] and gains.updates == 0
    for _ in range(30):  # confident: ~0.3 % after these
        assert gains.update(0.7e-3, 1e-3, 1e-3, 1e-10)
    assert gains.at(0.7e-3)[1] < 0.005
    for _ in range(30):  # the plant changes by 40 % (≫ the std): still learned from
        assert gains.update(0.7e-3, 1e-3, 1.4e-3, 1e-10)
    assert gains.at(0.7e-3)[0] > 1.15
    model = fresh()
    before = model.estimates_json()
    with caplog.at_level("WARNING", logger="feeder.pose_response"):
        model.learn("theta", 1, "fine", 2, (0.5086e-3, 0.0, 0.0), (0.5600e-3 * math.cos(0.2437),
                    0.5600e-3 * math.sin(0.2437), 2.851e-3))  # fmt: skip
    assert model.estimates_json()["theta/+/fine/orbit"] == before["theta/+/fine/orbit"]
    assert "theta/+/fine/orbit" in caplog.text and "not learned from" in caplog.text


@pytest.mark.parametrize("ratio", [3.0, 8.0, 0.1, -1.0])
def test_a_plant_several_times_off_its_seed_is_learned_from_two_alike_bursts(ratio: float) -> None:
    """A real device may respond several times more (or less) than the physics' seed: beyond the
    gate, but every burst alike.  The second such burst reopens the prior around it."""
    gains = GainFilter([0.0, 0.7e-3, 1.5e-3])
    noise = 1e-12
    learned = [gains.update(0.7e-3, 1e-3, ratio * 1e-3 * (1 + 0.02 * k), noise) for k in range(6)]
    assert learned[0] is (abs(ratio - 1) <= 1.5)  # one burst that far off: not learned from
    assert all(learned[1:])
    assert gains.at(0.7e-3)[0] == pytest.approx(ratio, rel=0.06)


def test_two_unlike_readings_of_other_motions_are_not_learned_from() -> None:
    """The loaded machine's misreadings gave gains of 228 and then −60: never alike."""
    gains = GainFilter([0.0, 0.7e-3, 1.5e-3])
    for measured in (0.24, -0.12, 0.4, 0.05, 0.24):
        assert not gains.update(0.5e-3, 2e-3, measured, 2 * (0.1e-6 / 0.5e-3) ** 2)
    assert gains.gain.tolist() == [1.0, 1.0, 1.0] and gains.updates == 0


def test_turn_table_is_bilinear_in_radius_and_periodic_in_orientation() -> None:
    rng = np.random.default_rng(7)
    radii, betas, period = (0.0, 1e-3, 2.5e-3), (0.0, math.pi / 4, math.pi / 2, 3 * math.pi / 4), math.pi
    orbit, radial, turn = (rng.normal(size=(3, 4)) for _ in range(3))
    table = TurnTable(radii, betas, orbit, radial, turn, period)
    assert table.at(1e-3, math.pi / 2) == pytest.approx((orbit[1, 2], radial[1, 2], turn[1, 2]), rel=1e-14)
    middle = table.at(1.75e-3, 5 * math.pi / 8)  # the middle of the cell r 1–2.5 mm, β 90–135°
    assert middle[2] == pytest.approx(turn[1:3, 2:4].mean(), rel=1e-13)
    wrapped = table.at(0.5e-3, 7 * math.pi / 8)  # between β = 135° and β = 180° ≡ 0°
    corners = orbit[0, 3] + orbit[0, 0] + orbit[1, 3] + orbit[1, 0]
    assert wrapped[0] == pytest.approx(0.25 * corners, rel=1e-13)
    assert table.at(1.2e-3, 0.3 + period) == pytest.approx(table.at(1.2e-3, 0.3), rel=1e-13)
    assert table.at(9e-3, 0.0) == pytest.approx((orbit[2, 0], radial[2, 0], turn[2, 0]), rel=1e-14)
