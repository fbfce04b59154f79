"""A part at O a little off in angle: the pose planner finishes the turn it went out for (fast,
on a model built by hand; no daemon).

The audit: a −10° turn of a part at O ended "oscillating" in 2 of 4 runs.  The fine θ step at O
was below a useful turn, so the part left by x for its turning station; that x burst turned it by
a few thousandths of a degree into the tolerance, the planner dropped the turn and brought it
back, the way back turned it out again, and the x bursts went ±20 steps out and back until the
reversals ended the move.
"""

from __future__ import annotations

import math

import numpy as np

from feeder.parts import Part
from feeder.plant.planar import PlanarPart
from feeder.plant.stick_slip import Friction
from feeder.pose import Pose
from feeder.pose_burst import AxisBurst, Finish
from feeder.pose_planner import DEFAULT_TOLERANCE_RAD, PosePlanner
from feeder.pose_response import ResponseModel, TurnTable
from feeder.pose_turns import USEFUL_TURN
from feeder.travel import Travel

SQUARE = PlanarPart.from_part(Part.parse("300x300x50"), Friction(105.25, 0.8))
TRAVEL = Travel((-2.4e-3, 2.4e-3), (-2.4e-3, 2.4e-3))
RADII = (0.0, 0.5e-3, 1e-3, 3e-3)
TRANSLATION = {
    (axis, mode): step for axis in ("x", "y") for mode, step in (("coarse", 2e-6), ("fine", 0.2e-6))
}
TRANSLATION_TURN_RAD = 0.1e-3
"""How much an x or y burst turns the part, against its direction (a burst and the one back
cancel): 0.006°, within the scatter of the embedded plane's readings."""
MAX_REVERSALS = 4
"""The daemon's default ``[control] max_reversals`` per axis (:mod:`feeder.daemon.burst_cycle`)."""


def table(orbit_mrad: tuple[float, ...], turn_mrad: tuple[float, ...]) -> TurnTable:
    """Per-step orbit and turn on :data:`RADII`, alike at every orientation, no radial drift."""
    period = math.pi / 2
    betas = tuple(period * j / 4 for j in range(4))
    orbit = 1e-3 * np.array(orbit_mrad)[:, None] * np.ones((1, 4))
    turn = 1e-3 * np.array(turn_mrad)[:, None] * np.ones((1, 4))
    return TurnTable(RADII, betas, orbit, np.zeros_like(orbit), turn, period)


def centre_model() -> ResponseModel:
    """The fine θ mode turns a part at O by 0.3 mrad a step, below :data:`USEFUL_TURN`
    tolerances (the plane's learned −θ fine step at O: 0.36 mrad against 0.39); 0.5 mm out it
    turns 0.9 mrad (the turning station); the coarse mode does not turn a part at O.  The −x
    coarse step is learned (the move that brought the part to O came that way), +x's is not."""
    model = ResponseModel(
        TRANSLATION,
        {
            "coarse": table((0.0, 2.0, 2.5, 2.5), (0.0, 4.0, 5.0, 5.0)),
            "fine": table((0.0, 0.4, 0.5, 0.5), (0.3, 0.9, 1.0, 1.0)),
        },
    )
    for start in (1e-3, 0.8e-3):
        model.learn("x", -1, "coarse", 100, (start, 0.0, 0.0), (start - 200e-6, 0.0, 0.0))
    assert model.learned("x", -1, "coarse") and not model.learned("x", 1, "coarse")
    return model


def play(model: ResponseModel, burst: AxisBurst, pose: Pose) -> Pose:
    """The plate: the model's own mean step, and an x or y burst turns the part against its direction."""
    x, y, psi = model.predict(burst.axis, burst.direction, burst.mode, burst.steps, pose)
    if burst.axis != "theta":
        psi -= burst.direction * TRANSLATION_TURN_RAD
    return x, y, psi


def test_the_fine_step_at_o_is_too_small_to_turn_there() -> None:
    model = centre_model()
    planner = PosePlanner(model, TRAVEL, SQUARE)
    assert planner.turns.update_station() == RADII[1]
    fine = abs(model.turn_step(-1, "fine", 0.0, 0.0, 0.0).turn_rad)
    assert fine < USEFUL_TURN * DEFAULT_TOLERANCE_RAD


def test_a_part_at_o_just_beyond_the_angle_tolerance_turns_and_does_not_ping_pong() -> None:
    """0.05 mrad beyond the tolerance at O: the part goes out towards its station, reads within
    the tolerance on the way (the x burst turned it), and goes on to turn (a θ burst aimed at the
    whole error) instead of coming back; then it comes back and the move ends done, with a
    reversal or two (it went ±30 x steps out and back, the angle 0.003° beyond the tolerance
    at the inner end, until the daemon's reversal count would end it "oscillating")."""
    model = centre_model()
    planner = PosePlanner(model, TRAVEL, SQUARE)
    tolerance = planner.tolerance_rad
    target: Pose = (0.0, 0.0, 0.0)
    pose: Pose = (0.0, 0.0, tolerance + 0.05e-3)
    last: dict[str, int] = {}
    reversals, played = 0, []
    for _ in range(40):
        nxt = planner.next_burst([pose], {1: target})
        if isinstance(nxt, Finish):
            break
        reversed_ = last.get(nxt.axis, nxt.direction) != nxt.direction
        reversals += reversed_
        assert reversals <= MAX_REVERSALS * 3, f"oscillating: {played}"
        last[nxt.axis] = nxt.direction
        after = play(model, nxt, pose)
        if not reversed_:  # as the daemon: the first burst after a reversal is not learned from
            planner.learn(nxt, [pose], [after])
        played.append((nxt.axis, nxt.direction, nxt.steps))
        pose = after
    assert isinstance(nxt, Finish) and nxt.status == "done", played
    assert abs(planner.turns.angle_error(pose, target)) <= tolerance
    assert math.hypot(pose[0], pose[1]) <= planner.tolerance_m
    assert any(axis == "theta" for axis, _, _ in played), played
    assert reversals <= 2, played


def test_a_trip_to_the_station_goes_on_when_a_reading_on_the_way_is_within_the_tolerance() -> None:
    """The first burst leaves O for the station; after it the angle reads within the tolerance,
    and the next burst still serves the turn (on outwards, or θ), not the way back to O."""
    model = centre_model()
    planner = PosePlanner(model, TRAVEL, SQUARE)
    target: Pose = (0.0, 0.0, 0.0)
    start: Pose = (0.0, 0.0, planner.tolerance_rad + 0.05e-3)
    out = planner.next_burst([start], {1: target})
    assert isinstance(out, AxisBurst) and out.axis != "theta"
    there = play(model, out, start)
    assert abs(planner.turns.angle_error(there, target)) <= planner.tolerance_rad
    nxt = planner.next_burst([there], {1: target})
    assert isinstance(nxt, AxisBurst)
    assert nxt.axis == "theta" or (nxt.axis, nxt.direction) == (out.axis, out.direction), nxt
