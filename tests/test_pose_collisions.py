"""θ bursts and targets keep parts apart (the pose planner's clearance), on models built by hand (fast)."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from scipy.spatial import cKDTree

from feeder.footprint import gap_m
from feeder.parts import Part
from feeder.plant.limit_surface import Patch
from feeder.plant.planar import PlanarPart
from feeder.plant.stick_slip import Friction
from feeder.pose import Pose
from feeder.pose_burst import AxisBurst, Finish
from feeder.pose_gain import SEED_STD
from feeder.pose_planner import PosePlanner
from feeder.pose_response import ResponseModel, TurnTable
from feeder.pose_turns import CLEARANCE_M
from feeder.travel import Travel

FRICTION = Friction(105.25, 0.8)
SQUARE = PlanarPart.from_part(Part.parse("300x300x50"), FRICTION)
DISC = PlanarPart.from_part(Part.parse("300x300x50"), FRICTION, shape="disc")
TRAVEL = Travel((-2.5e-3, 2.5e-3), (-2.5e-3, 2.5e-3))
RADII = (0.0, 0.5e-3, 1e-3, 3e-3)
TRANSLATION = {
    (axis, mode): step for axis in ("x", "y") for mode, step in (("coarse", 2e-6), ("fine", 0.2e-6))
}
PESSIMISTIC = 1 + 2 * SEED_STD
"""The planner's per-step scale for a model with no burst learned (mean + 2σ, σ = 30 %)."""


def table(
    orbit_mrad: tuple[float, ...],
    turn_mrad: tuple[float, ...],
    period: float,
    radii: tuple[float, ...] = RADII,
) -> TurnTable:
    """Per-step orbit and turn on ``radii``, the same at every orientation, no radial drift."""
    betas = tuple(period * j / 4 for j in range(4)) if period > 0 else (0.0,)
    columns = np.ones((1, len(betas)))
    orbit = 1e-3 * np.array(orbit_mrad)[:, None] * columns
    turn = 1e-3 * np.array(turn_mrad)[:, None] * columns
    return TurnTable(radii, betas, orbit, np.zeros_like(orbit), turn, period)


def turning_model() -> ResponseModel:
    """The daemon's θ drive as the review saw it: a part at O turns in place; one 0.36 mm out
    orbits ~1.6× and turns ~1.8× as much (it orbited 65° and turned 73° while part 1 turned 40°)."""
    period = math.pi / 2
    return ResponseModel(
        TRANSLATION,
        {
            "coarse": table((0.0, 22.0, 25.0, 25.0), (10.0, 21.0, 25.0, 25.0), period),
            "fine": table((0.0, 4.4, 5.0, 5.0), (2.0, 4.2, 5.0, 5.0), period),
        },
    )


def step_all(model: ResponseModel, burst: AxisBurst, poses: list[Pose], scale: float) -> list[list[Pose]]:
    """Every part's pose after each step of ``burst`` (``scale``: every step's multiplier)."""
    path, now = [], list(poses)
    for _ in range(burst.steps):
        now = [model.predict("theta", burst.direction, burst.mode, 1, p, scale) for p in now]
        path.append(now)
    return path


def test_a_theta_burst_stops_before_the_parts_touch_and_the_move_ends_naming_the_other_part() -> None:
    """The review: two 300 µm squares 0.36 mm apart (centre to centre), part 1 at O asked to turn
    40°.  Turned all the way (as the bursts were before the cut), part 2 touches part 1.  The
    bursts towards it each keep the footprints CLEARANCE_M apart by the planner's own
    pessimistic prediction (and by the mean, which plays the plate here), and the move ends
    naming part 2 (part 2 has no target, so `check` lets the move start)."""
    model = turning_model()
    planner = PosePlanner(model, TRAVEL, SQUARE)
    poses: list[Pose] = [(0.0, 0.0, 0.0), (0.36e-3, 0.0, 0.0)]
    target = (0.0, 0.0, math.radians(40))
    whole_turn = AxisBurst("theta", 1, math.ceil(target[2] / 10e-3), "coarse")  # 40° at 10 mrad/step
    assert min(gap_m(SQUARE.patch, *after) for after in step_all(model, whole_turn, poses, 1.0)) == 0.0
    bursts = 0
    for _ in range(50):
        nxt = planner.part_burst(poses, 0, target)
        if isinstance(nxt, Finish):
            break
        assert nxt.axis == "theta"
        for scale in (PESSIMISTIC, 1.0):
            for after in step_all(model, nxt, poses, scale):
                assert gap_m(SQUARE.patch, *after) >= CLEARANCE_M, (nxt, after)
        poses = step_all(model, nxt, poses, 1.0)[-1]
        bursts += 1
    assert bursts >= 1  # the part was turned as far as the clearance allows
    assert isinstance(nxt, Finish) and nxt.status == "unreachable"
    assert "turning part 1" in nxt.reason and "part 2" in nxt.reason and "\n" not in nxt.reason
    assert poses[0][2] > math.radians(3)  # it did turn some
    assert planner.check({1: target}, [(0.0, 0.0, 0.0), (0.36e-3, 0.0, 0.0)]) is None


def _outline(patch: Patch, pose: Pose, spacing: float) -> np.ndarray:
    """Points every ``spacing`` (m) along the outline of the footprint at ``pose`` (NaN angle: the
    circumscribed circle)."""
    x, y, psi = pose
    if patch.shape == "disc" or math.isnan(psi):
        r = patch.radius_m
        t = np.linspace(0.0, 2 * math.pi, int(2 * math.pi * r / spacing), endpoint=False)
        return np.column_stack([x + r * np.cos(t), y + r * np.sin(t)])
    hl, hw = patch.length_m / 2, patch.width_m / 2
    corners = [(hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw), (hl, hw)]
    local = np.concatenate(
        [
            np.linspace(corners[k], corners[k + 1], int(math.dist(corners[k], corners[k + 1]) / spacing) + 1)
            for k in range(4)
        ]
    )
    c, s = math.cos(psi), math.sin(psi)
    return np.column_stack([x + c * local[:, 0] - s * local[:, 1], y + s * local[:, 0] + c * local[:, 1]])


@pytest.mark.parametrize("size", ["500x300x50", "300x300x50"])
def test_the_gap_between_footprints_is_the_sampled_outlines_distance(size: str) -> None:
    """Against outlines sampled every 1 µm: the smallest distance between their points (a k-d
    tree's nearest neighbours; about 0
    where the outlines cross, i.e. the footprints overlap; equal footprints cannot hold each
    other), within the sampling's 1 µm.  Rectangles, a rectangle and a part at any angle (NaN),
    two at any angle, side by side to 0.8 mm apart."""
    patch = PlanarPart.from_part(Part.parse(size), FRICTION).patch
    rng = random.Random(5)
    spacing = 1e-6
    cases = 0
    for _ in range(60):
        a = (rng.uniform(-1e-3, 1e-3), rng.uniform(-1e-3, 1e-3), rng.uniform(-math.pi, math.pi))
        heading, distance = rng.uniform(-math.pi, math.pi), rng.uniform(0.25e-3, 0.8e-3)
        b = (
            a[0] + distance * math.cos(heading),
            a[1] + distance * math.sin(heading),
            rng.uniform(0, math.pi),
        )
        for pa, pb in ((a, b), (a, (*b[:2], math.nan)), ((*a[:2], math.nan), (*b[:2], math.nan))):
            pts_a, pts_b = _outline(patch, pa, spacing), _outline(patch, pb, spacing)
            sampled = float(cKDTree(pts_b).query(pts_a)[0].min())
            assert gap_m(patch, pa, pb) == pytest.approx(sampled, abs=spacing), (pa, pb)
            cases += gap_m(patch, pa, pb) > 0
    assert cases > 30  # apart and overlapping both tried


def test_the_gap_of_squares_side_by_side_is_exact_not_their_circles() -> None:
    """The review's pair, side by side 0.36 mm apart: 60 µm, though their circumscribed circles
    overlap; turned 45°, one reaches 212 µm towards the other; discs: centres less diameter."""
    square = SQUARE.patch
    assert gap_m(square, (0.0, 0.0, 0.0), (0.36e-3, 0.0, 0.0)) == pytest.approx(60e-6, abs=1e-12)
    assert gap_m(square, (0.0, 0.0, 0.0), (0.4e-3, 0.0, math.pi / 4)) == pytest.approx(
        0.4e-3 - 150e-6 - 150e-6 * math.sqrt(2), abs=1e-12
    )
    assert gap_m(square, (0.0, 0.0, 0.0), (0.36e-3, 0.0, math.pi / 4)) == 0.0
    assert gap_m(DISC.patch, (0.0, 0.0, 0.3), (0.32e-3, 0.0, -1.0)) == pytest.approx(20e-6, abs=1e-12)


def test_parts_closer_than_the_clearance_may_move_apart_but_not_closer() -> None:
    """Two 300 µm discs 20 µm apart (under the clearance): part 1 held near O (dead zone), part 2
    orbiting O away from it is not cut; orbiting towards it, not one step is given, and the
    planner says which part is in the way."""
    radii = (0.0, 0.25e-3, 0.5e-3, 3e-3)  # nothing moves within 0.25 mm of O
    still = (0.0, 0.0, 0.0, 0.0)
    orbiting = ResponseModel(
        TRANSLATION,
        {
            "coarse": table((0.0, 0.0, 5.0, 5.0), still, 0.0, radii),
            "fine": table((0.0, 0.0, 1.0, 1.0), still, 0.0, radii),
        },
    )
    planner = PosePlanner(orbiting, TRAVEL, DISC)
    phi = math.acos((0.5e-3**2 + 0.2e-3**2 - 0.32e-3**2) / (2 * 0.5e-3 * 0.2e-3))
    near = [(0.2e-3, 0.0, 0.0), (0.5e-3 * math.cos(phi), 0.5e-3 * math.sin(phi), 0.0)]
    assert gap_m(DISC.patch, *near) == pytest.approx(20e-6, abs=1e-9) and CLEARANCE_M > 20e-6
    away = planner.turns.theta_burst(near, 1, 0.3, quantity="orbit")
    far = [(-0.2e-3, 0.0, 0.0), near[1]]  # part 1 out of the way: the burst nothing cuts
    assert isinstance(away, AxisBurst) and away == planner.turns.theta_burst(far, 1, 0.3, quantity="orbit")
    end = step_all(orbiting, away, near, PESSIMISTIC)[-1]
    assert gap_m(DISC.patch, *end) > CLEARANCE_M
    towards = planner.turns.theta_burst(near, 1, -0.3, quantity="orbit")
    assert isinstance(towards, Finish) and towards.status == "unreachable"
    assert "orbiting part 2" in towards.reason and "part 1" in towards.reason
    assert isinstance(planner.turns.theta_burst(far, 1, -0.3, quantity="orbit"), AxisBurst)


def test_check_refuses_a_target_within_the_clearance_of_another_target_naming_both() -> None:
    """Another part's target (a held part's; any angle: its circumscribed circle) is an obstacle;
    a part without one is not: x/y bursts carry it along, so a target where it lies now is an
    ordinary translation (it was refused)."""
    planner = PosePlanner(turning_model(), TRAVEL, SQUARE)
    poses: list[Pose] = [(-1e-3, 0.0, 0.0), (0.45e-3, 0.0, 0.0)]
    assert planner.check({1: (0.45e-3, 0.0, 0.0)}, poses) is None  # part 2 moves along: no obstacle
    held = (0.45e-3, 0.0, math.nan)  # 212 µm round, as any angle may put its corners
    assert planner._crowded_target({1: (0.0, 0.0, 0.0), 2: held}, poses) is None  # 88 µm apart
    for target, words in (
        ((0.05e-3, 0.0, 0.0), "comes within 3.79e-05 m of part 2's target"),
        ((0.0, 0.0, 0.8), "comes within"),  # turned 46°: a corner 26 µm from part 2's circle
        ((0.2e-3, 0.0, 0.0), "overlaps part 2's target"),
    ):
        reason = planner.check({1: target, 2: held}, poses)
        assert reason is not None and words in reason and "part 1" in reason and "\n" not in reason
    close: list[Pose] = [(0.0, 0.0, 0.0), (0.32e-3, 0.0, 0.0)]  # 20 µm apart already
    assert planner._crowded_target({1: (-1e-6, 0.0, 0.0), 2: close[1]}, close) is None  # moving apart
    refused = planner.check({1: (1e-6, 0.0, 0.0), 2: close[1]}, close)  # closer still
    assert refused is not None and "comes within 1.9e-05 m of part 2's target" in refused
