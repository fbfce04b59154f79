"""Pose planner: steps used against the fewest the plant model allows, and against a naive planner, same run.

A 500×300×50 part on the planar plant (tests/test_pose_planner.py's World:
ideal sawtooth bursts on :class:`PlanarStickSlip`) is brought to random pose
targets.  ``lower_bound_steps`` per target = |Δx|/coarse x step + |Δy|/coarse y
step + |Δψ|/(largest coarse turn per step anywhere): no plan can use fewer.
The naive baseline is the same planner given fine modes only.  ``ratio`` =
naive steps / our steps (higher is better); ``steps_over_bound`` = our steps
/ lower bound; also the median simulated time per target (steps / 100 Hz) and
the planner's own wall time per decision.
"""

from __future__ import annotations

import math
import random
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_pose_planner import MODES, PART, RADII, TRAVEL, World, fresh

from feeder.pose_burst import Finish
from feeder.pose_planner import PosePlanner
from feeder.pose_response import ResponseModel


def _fine_only(model: ResponseModel) -> ResponseModel:
    return ResponseModel(
        {k: v for k, v in model.translation.items() if k[1] == "fine"}, {"fine": model.turn["fine"]}
    )


def _drive(planner: PosePlanner, targets: list[tuple[float, float, float]]) -> tuple[list[int], float, int]:
    world = World([(0.0, 0.0, 0.0)])
    steps, think, decisions = [], 0.0, 0
    for target in targets:
        before_steps = world.steps
        for _ in range(400):
            before = world.poses()
            t0 = time.perf_counter()
            nxt = planner.next_burst(before, {1: target})
            think += time.perf_counter() - t0
            decisions += 1
            if isinstance(nxt, Finish):
                break
            world.burst(nxt)
            planner.learn(nxt, before, world.poses())
        steps.append(world.steps - before_steps)
    return steps, think, decisions


def run(quick: bool) -> dict:
    rng = random.Random(20)
    count = 3 if quick else 20
    targets = [
        (rng.uniform(-1e-3, 1e-3), rng.uniform(-1e-3, 1e-3), rng.uniform(0, math.pi)) for _ in range(count)
    ]
    model = fresh()
    coarse_x = model.translation[("x", "coarse")]
    coarse_y = model.translation[("y", "coarse")]
    best_turn = float(abs(model.turn["coarse"].turn_rad).max())
    bound, previous = [], (0.0, 0.0, 0.0)
    for t in targets:
        dpsi = abs(math.remainder(t[2] - previous[2], math.pi))
        bound.append(
            abs(t[0] - previous[0]) / coarse_x + abs(t[1] - previous[1]) / coarse_y + dpsi / best_turn
        )
        previous = t
    ours, think, decisions = _drive(PosePlanner(model, TRAVEL, PART), targets)
    naive, _, _ = _drive(PosePlanner(_fine_only(fresh()), TRAVEL, PART), targets)
    return {
        "ratio": sum(naive) / sum(ours),
        "steps": sum(ours),
        "naive_steps": sum(naive),
        "lower_bound_steps": round(sum(bound)),
        "steps_over_bound": sum(ours) / sum(bound),
        "median_simulated_time_s": statistics.median(ours) / 100.0,
        "decision_wall_s": think / decisions,
        "targets": count,
        "radii_m": list(RADII),
        "modes": [m.mode + "/" + m.axis for m in MODES],
    }
