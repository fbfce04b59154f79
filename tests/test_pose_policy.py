"""The policy over poses: three axes, a pose navigator, a fake clock and a kinematic plate (no I/O).

The plate here is a toy (each x/y step moves every part by the same step; each θ step turns
every part about O by a fixed angle), so the test checks the policy's plumbing with the real
navigator and a planner that steers by it: which axis each command addresses, that targets
given in part keep the rest of the pose, that a reached part is held, the result's pose errors.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import pytest

from feeder.daemon.jobs import Command, Completion, Decide, Finished, Job, LoopSettings, Started, StepMode
from feeder.daemon.line_navigator import COARSE, FINE
from feeder.daemon.policy import Policy
from feeder.daemon.pose_navigator import PoseNavigator
from feeder.drivers.amplifier import DriveSettings
from feeder.pose import Pose, pose_error
from feeder.pose_burst import AxisBurst, Finish

STEP_M = 1e-6
TURN_RAD = 1e-3
MODES = {
    COARSE: StepMode(COARSE, DriveSettings(1000.0, 100.0), STEP_M, (0.9 * STEP_M, 1.1 * STEP_M)),
    FINE: StepMode(FINE, DriveSettings(1000.0, 40.0), STEP_M, (0.9 * STEP_M, 1.1 * STEP_M)),
}
SETTINGS = LoopSettings(
    tolerance_m=1e-6, tolerance_rad=1e-3, settle_s=0.02, average_samples=2, min_y_m=-1e-3, max_y_m=1e-3,
    min_position_m=-1e-3, max_position_m=1e-3,
)  # fmt: skip
DT = 0.01


class StepPlanner:
    """Turns first (θ about O), then x, then y, in whole steps of the toy plate; refuses a
    second part's target it would have to move the first one for."""

    def __init__(self) -> None:
        self.learned: list[tuple[str, int]] = []

    def check(self, targets: dict[int, Pose], poses: list[Pose]) -> str | None:
        if len(targets) > 1:
            return "the toy plate moves every part alike: two targets cannot be reached together"
        return None

    def next_burst(self, poses: list[Pose], targets: dict[int, Pose]) -> AxisBurst | Finish:
        ((pid, target),) = targets.items()
        x, y, psi = poses[pid - 1]
        for axis, error, unit, tol in (
            ("theta", target[2] - psi, TURN_RAD, SETTINGS.tolerance_rad),
            ("x", target[0] - x, STEP_M, SETTINGS.tolerance_m),
            ("y", target[1] - y, STEP_M, SETTINGS.tolerance_m),
        ):
            if abs(error) > tol / 2 and round(abs(error) / unit) >= 1:
                return AxisBurst(axis, 1 if error > 0 else -1, round(abs(error) / unit), FINE)
        return Finish("done", "every part within tolerance")

    def learn(self, burst: AxisBurst, before: list[Pose], after: list[Pose]) -> None:
        self.learned.append((burst.axis, burst.direction * burst.steps))

    def burst_effect(self, burst: AxisBurst, poses: list[Pose]) -> list[tuple[float, float]]:
        moved = (0.0, burst.steps * TURN_RAD) if burst.axis == "theta" else (burst.steps * STEP_M, 0.0)
        return [moved] * len(poses)

    def estimates_json(self) -> dict[str, object]:
        return {"bursts": len(self.learned)}


@dataclass
class Plane:
    """A policy with the pose navigator, a fake clock and a toy plate with two parts."""

    poses: list[Pose] = field(default_factory=lambda: [(100e-6, 0.0, 0.0), (-300e-6, 200e-6, 0.5)])
    planner: StepPlanner = field(default_factory=StepPlanner)
    now: float = 0.0
    commands: list[Command] = field(default_factory=list)

    def __post_init__(self) -> None:
        navigator = PoseNavigator(self.planner, SETTINGS, math.pi / 2)  # type: ignore[arg-type]
        axis_modes = {a: MODES for a in ("x", "y", "theta")}
        self.policy = Policy(MODES, SETTINGS, axis_modes=axis_modes, navigator=navigator)

    def play(self, command: Command) -> None:
        """The amplifier: a step command moves the plate at once; everything else just completes."""
        if command.kind == "step":
            n = command.steps
            if command.axis == "x":
                self.poses = [(x + n * STEP_M, y, p) for x, y, p in self.poses]
            elif command.axis == "y":
                self.poses = [(x, y + n * STEP_M, p) for x, y, p in self.poses]
            else:
                c, s = math.cos(n * TURN_RAD), math.sin(n * TURN_RAD)
                self.poses = [(c * x - s * y, s * x + c * y, p + n * TURN_RAD) for x, y, p in self.poses]
        self.policy.on_completion(Completion(command, self.now, counter=0))

    def sample(self) -> None:
        """The camera sees every part."""
        self.policy.on_sample(self.poses[0][0], self.now, tuple(self.poses))

    def run(self, job: Job, limit: int = 3000) -> Finished:
        self.sample()
        assert self.policy.submit(job, self.now) is None
        for _ in range(limit):
            self.now += DT
            self.sample()
            finished = tick(self.policy, self.now, self.commands, self.play)
            if finished is not None:
                return finished
        raise AssertionError("the job did not finish")


def tick(
    policy: Policy, now: float, commands: list[Command], play: Callable[[Command], None]
) -> Finished | None:
    """One tick of ``policy`` as the loop runs it: records taken at once, decisions answered,
    commands kept in ``commands`` and played; the job's end, or None."""
    for out in policy.tick(now):
        if isinstance(out, Started):
            out.job.recorded = True
        elif isinstance(out, Decide):  # the loop's worker: answered by the next tick
            policy.on_decision(policy.decide(out))
        elif isinstance(out, Command):
            commands.append(out)
            play(out)
        elif isinstance(out, Finished):
            return out
    return None


def test_a_pose_move_steps_each_axis_and_reports_the_pose_errors() -> None:
    plane = Plane()
    target = (300e-6, -100e-6, 0.2)
    done = plane.run(Job("move", pose_target={"x_m": target[0], "y_m": target[1], "angle_rad": target[2]}))
    result = done.result
    assert result.status == "done", result.reason
    assert result.target_pose == target and result.part == 1
    assert result.reached_pose is not None and result.error_m is not None and result.error_rad is not None
    distance, angle = pose_error(plane.poses[0], target, math.pi / 2)
    assert (
        result.error_m == distance <= SETTINGS.tolerance_m
        and result.error_rad == angle <= SETTINGS.tolerance_rad
    )
    steps = [c for c in plane.commands if c.kind == "step"]
    assert {c.axis for c in steps} == {"x", "y", "theta"}
    applied = {(c.axis, c.mode) for c in plane.commands if c.kind == "apply"}
    assert applied == {("x", FINE), ("y", FINE), ("theta", FINE)}  # every axis loads its own waveform
    assert [c.kind for c in plane.commands].count("enable") == 1  # one enable leaves ground on every axis
    assert result.bursts_per_axis == {"theta": 1, "x": 1, "y": 1}
    assert result.as_dict()["pose"] == list(result.reached_pose)


def test_a_partial_target_keeps_the_rest_of_the_pose_and_a_second_part_is_refused_while_one_is_held() -> None:
    plane = Plane()
    start = plane.poses[0]
    done = plane.run(Job("move", pose_target={"angle_rad": 0.3}))
    assert done.result.status == "done"
    assert done.result.target_pose == (start[0], start[1], 0.3)  # x and y as they were at the start
    refused = plane.policy.submit(Job("move", pose_target={"x_m": 0.0}, part=2), plane.now)
    assert refused is not None and "cannot be reached together" in refused  # part 1 is held at its target
    assert plane.policy.submit(Job("move", pose_target={"x_m": 0.0}, part=3), plane.now) == (
        "part 3 is not on the plate (the camera sees 2 part(s))"
    )


def test_a_part_is_held_only_when_its_done_is_acted_on() -> None:
    """A "done" answered after a stop (the planner works off the tick) holds nothing."""
    plane = Plane()
    here = plane.poses[0]
    job = Job("move", pose_target={"x_m": here[0], "y_m": here[1], "angle_rad": here[2]})
    plane.sample()
    assert plane.policy.submit(job, plane.now) is None
    asked: list[Decide] = []
    while not asked:
        plane.now += DT
        plane.sample()
        for out in plane.policy.tick(plane.now):
            if isinstance(out, Started):
                out.job.recorded = True
            elif isinstance(out, Command):
                plane.play(out)
            elif isinstance(out, Decide):
                asked.append(out)
        assert plane.now < 5
    plane.policy.request_stop("operator")
    decision = plane.policy.decide(asked[0])
    assert decision.answer == ("done", "every part within tolerance")
    plane.policy.on_decision(decision)
    for _ in range(10):
        plane.now += DT
        plane.sample()
        plane.policy.tick(plane.now)
    assert plane.policy.last_result is not None and plane.policy.last_result.status == "stopped"
    navigator = plane.policy.navigator
    assert isinstance(navigator, PoseNavigator) and navigator.held == {}
    assert plane.run(Job("move", pose_target={"angle_rad": here[2]})).result.status == "done"
    assert navigator.held == {1: here}


def test_targets_outside_the_travel_and_parts_leaving_it() -> None:
    plane = Plane()
    assert plane.policy.submit(Job("move", pose_target={"y_m": 0.0}), plane.now) == (
        "position uncertain: no camera reading yet"
    )
    plane.sample()
    refused = plane.policy.submit(Job("move", pose_target={"y_m": 2e-3}), plane.now)
    assert refused is not None and "outside the travel" in refused and "y [-0.001, 0.001] m" in refused
    # another part outside the travel, carried further out (a move leaving it be goes on: test_pose_edges)
    plane.poses[1] = (0.0, 1.5e-3, 0.0)
    done = plane.run(Job("move", pose_target={"y_m": 100e-6}))
    assert done.result.status == "limit" and done.result.reason.startswith("part 2 at (0, 0.0016) m")
    assert "further out than at the move's start, (0, 0.0015) m" in done.result.reason


@pytest.mark.parametrize("angle", [1e18, -7.0, 90.0])
def test_an_angle_beyond_one_turn_is_refused(angle: float) -> None:
    """1e18 rad was accepted and turned the plate for 40 s (169 bursts); 90 is likely degrees."""
    plane = Plane()
    plane.sample()
    refused = plane.policy.submit(Job("move", pose_target={"angle_rad": angle}), plane.now)
    assert refused is not None and refused.startswith("angle_rad must lie within ±2π (one turn)")


def test_an_angle_within_one_turn_is_taken_modulo_a_turn() -> None:
    plane = Plane()
    plane.sample()
    job = Job("move", pose_target={"angle_rad": 2 * math.pi - 0.1})
    assert plane.policy.submit(job, plane.now) is None
    assert job.target_pose is not None and job.target_pose[2] == pytest.approx(-0.1, abs=1e-12)


def test_a_one_axis_move_on_the_plane_is_a_move_of_part_ones_x() -> None:
    plane = Plane()
    done = plane.run(Job("move", target_m=150e-6))
    assert done.result.status == "done" and done.result.target_pose == (150e-6, 0.0, 0.0)
    assert abs(plane.poses[0][0] - 150e-6) <= SETTINGS.tolerance_m


class ScriptedPlanner(StepPlanner):
    """Bursts from a script, then done (a planner's decisions, whatever the poses)."""

    def __init__(self, script: list[tuple[str, int]], path: bool = False) -> None:
        super().__init__()
        self.script = list(script)
        self.path = path

    def next_burst(self, poses: list[Pose], targets: dict[int, Pose]) -> AxisBurst | Finish:
        if not self.script:
            return Finish("done", "every part within tolerance")
        axis, direction = self.script.pop(0)
        return AxisBurst(axis, direction, 1, FINE, self.path)


def test_reversals_are_counted_per_axis() -> None:
    """x+ then y− is no reversal (a pair's way to its anchor alternates them); x+ then x− is."""
    limit = SETTINGS.max_reversals * 3  # three axes
    crossing = [("x", 1), ("y", -1)] * (limit + 4)  # 2·limit + 7 sign changes across axes, none per axis
    assert Plane(planner=ScriptedPlanner(crossing)).run(
        Job("move", pose_target={"x_m": 0.0})
    ).result.status == ("done")
    back_and_forth = [("x", 1), ("x", -1)] * (limit + 1)
    result = Plane(planner=ScriptedPlanner(back_and_forth)).run(Job("move", pose_target={"x_m": 0.0})).result
    assert result.status == "oscillating" and result.reason.startswith(f"{limit + 1} direction reversals")
    # a planned path's legs (a pair's A kept at its moving anchor, 2-6 µm either way) are not
    # counted: a CANopen pair ended "oscillating" on its way; max_bursts bounds them
    path = Plane(planner=ScriptedPlanner(back_and_forth, path=True))
    assert path.run(Job("move", pose_target={"x_m": 0.0})).result.status == "done"
    endless = [("x", 1), ("x", -1)] * SETTINGS.max_bursts * 3
    endless_path = Plane(planner=ScriptedPlanner(endless, path=True))
    result = endless_path.run(Job("move", pose_target={"x_m": 0.0})).result
    assert result.status == "unreachable" and result.bursts == SETTINGS.max_bursts * 3, result
