"""Held parts on the plane (feeder/daemon/pose_navigator.py): a hold keeps what its move asked for,
`release` lets parts go, refusals caused by holds say how; a move's result reports "any angle" as
such and the reached angle on the target's branch (feeder/daemon/jobs.py, feeder/cli/control.py)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from test_pose_policy import SETTINGS, Plane

from feeder.cli.control import _print_result
from feeder.daemon.jobs import Burst, Job, JobResult
from feeder.daemon.move_records import MoveRecords
from feeder.daemon.pose_navigator import PoseNavigator
from feeder.daemon.replies import MoveResult
from feeder.daemon.step_estimator import BACKWARD, FORWARD
from feeder.daemon.store import Store
from feeder.pose import Pose
from feeder.pose_burst import AxisBurst, Finish


def navigator_of(plane: Plane) -> PoseNavigator:
    navigator = plane.policy.navigator
    assert isinstance(navigator, PoseNavigator)
    return navigator


def test_a_hold_keeps_the_angle_only_when_the_move_asked_for_one() -> None:
    plane = Plane()
    assert plane.run(Job("move", pose_target={"x_m": 300e-6})).result.status == "done"
    x, y, psi = navigator_of(plane).held[1]
    assert (x, y) == (300e-6, 0.0) and math.isnan(psi)  # no angle asked: any angle is held
    assert navigator_of(plane).holds() == [{"part": 1, "pose": [300e-6, 0.0, None]}]
    assert plane.run(Job("move", pose_target={"angle_rad": 0.2})).result.status == "done"
    assert navigator_of(plane).held[1] == (300e-6, 0.0, 0.2)  # re-placed, with the angle asked


def test_a_held_part_moved_in_angle_alone_keeps_its_held_x_and_y() -> None:
    """A θ jog (or a move giving only the angle, or y) of a held part: what it does not give stays
    at the hold, not at the reading within the tolerance of it (each jog moved the hold there,
    and holds drifted jog by jog)."""
    plane = Plane()
    assert plane.run(Job("move", pose_target={"x_m": 300e-6})).result.status == "done"
    x, y, psi = plane.poses[0]
    plane.poses[0] = (x + 0.4e-6, y - 0.3e-6, psi)  # the camera sees it within the tolerance
    assert plane.run(Job("move", pose_target={"angle_rad": 0.2})).result.status == "done"
    assert navigator_of(plane).held[1] == (300e-6, 0.0, 0.2)
    assert plane.run(Job("move", pose_target={"y_m": 10e-6})).result.status == "done"
    assert navigator_of(plane).held[1][:2] == (300e-6, 10e-6)


def test_a_held_angle_stays_when_a_move_gives_only_x_or_y() -> None:
    """An x jog of a part held at an angle dropped the angle from the hold (any angle after it),
    so later moves let it drift.  (The second part of a held pair still moves with its angle
    free: the pair strategy turns it as it orbits.)"""
    plane = Plane()
    assert plane.run(Job("move", pose_target={"x_m": 300e-6, "angle_rad": 0.2})).result.status == "done"
    assert plane.run(Job("move", pose_target={"x_m": 310e-6})).result.status == "done"
    assert navigator_of(plane).held[1] == (310e-6, 0.0, 0.2)
    assert plane.run(Job("move", by_m=-10e-6)).result.status == "done"
    assert navigator_of(plane).held[1] == (300e-6, 0.0, 0.2)


def test_a_refusal_caused_by_a_hold_names_it_and_release_lets_it_go() -> None:
    plane = Plane()
    assert plane.run(Job("move", pose_target={"x_m": 300e-6})).result.status == "done"
    refused = plane.policy.submit(Job("move", pose_target={"x_m": 0.0}, part=2), plane.now)
    assert refused is not None
    assert refused.endswith("(held: part 1; `feeder release` lets held parts go)")
    navigator = navigator_of(plane)
    assert navigator.release(2) == [] and navigator.held.keys() == {1}  # part 2 was not held
    assert navigator.release() == [1] and navigator.holds() == []
    done = plane.run(Job("move", pose_target={"x_m": 0.0}, part=2))
    assert done.result.status == "done"
    assert navigator.holds() == [{"part": 2, "pose": [0.0, 200e-6, None]}]


def test_a_move_of_a_held_part_that_does_not_end_done_leaves_it_unheld() -> None:
    plane = Plane()
    assert plane.run(Job("move", pose_target={"x_m": 300e-6})).result.status == "done"
    job = Job("move", pose_target={"x_m": 900e-6})
    plane.sample()
    assert plane.policy.submit(job, plane.now) is None
    assert 1 not in navigator_of(plane).held  # its old target no longer holds it
    plane.policy.request_stop("operator")


class _PlacedPair:
    """A planner that finds its parts placed, on a drive whose θ has the anchoring orbit modes."""

    class model:  # the planner's response model, as the navigator reads it
        @staticmethod
        def orbit_modes() -> list[str]:
            return ["anchor", "anchor-fine"]

    def __init__(self) -> None:
        self.learned: list[AxisBurst] = []

    def check(self, targets: dict[int, Pose], poses: list[Pose]) -> str | None:
        return None

    def next_burst(self, poses: list[Pose], targets: dict[int, Pose]) -> Finish:
        return Finish("done", "every part within tolerance")

    def learn(self, burst: AxisBurst, before: list[Pose], after: list[Pose]) -> None:
        self.learned.append(burst)


def test_parts_placed_together_are_done_only_with_theta_resting_at_zero_volts() -> None:
    """After backward θ steps the output rests at the top of its table; the done check's ground
    then turns the plate about O and the pair with it (a CANopen pair read 2.3–4.3 µm off after
    each of 4 grounds).  So a placed pair first gets one forward step of θ's finest orbit mode,
    not learned from (the plate's turn to 0 V is most of what it does), unless θ's last burst
    went forward; a single part is done at once (its own turn corrects the ground's)."""
    planner = _PlacedPair()
    navigator = PoseNavigator(planner, SETTINGS, math.pi / 2)  # type: ignore[arg-type]
    reading = ((0.0, 0.0, 0.0), (1.0e-3, 0.0, 0.0))
    navigator.held[1] = reading[0]
    job = Job("move", pose_target={"x_m": 1.0e-3}, part=2)
    assert navigator.prepare(job, reading) is None
    zeroing = Burst("anchor-fine", FORWARD, 1, "theta")
    assert navigator.next_burst(job, reading) == zeroing  # unknown since the start: not 0 V
    navigator.learn(zeroing, True, reading, reading)
    assert planner.learned == []
    assert navigator.next_burst(job, reading) == ("done", "every part within tolerance")
    orbit = Burst("anchor", BACKWARD, 40, "theta")
    navigator.learn(orbit, True, reading, reading)
    assert planner.learned == [AxisBurst("theta", -1, 40, "anchor")]
    translated = Burst("fine", FORWARD, 2, "x")  # x's rest leaves θ's as it is
    navigator.learn(translated, True, reading, reading)
    assert navigator.next_burst(job, reading) == zeroing
    navigator.release(1)
    single = Job("move", pose_target={"x_m": 1.0e-3}, part=2)
    assert navigator.prepare(single, reading) is None
    assert navigator.next_burst(single, reading) == ("done", "every part within tolerance")


def result(**changes: object) -> JobResult:
    base: dict[str, object] = dict(
        kind="move", status="done", reason="every part within tolerance", target_m=1e-3, start_m=0.0,
        reached_m=1e-3, steps=10, bursts=2, duration_s=1.0, estimates={}, part=2,
        target_pose=(1e-3, 0.5e-3, 0.3), start_pose=(0.0, 0.0, 0.0), reached_pose=(1e-3, 0.5e-3, 0.3),
        symmetry_rad=math.pi / 2,
    )  # fmt: skip
    base.update(changes)
    return JobResult(**base)  # type: ignore[arg-type]


def test_any_angle_is_reported_as_none_not_as_an_invented_angle(capsys: pytest.CaptureFixture[str]) -> None:
    free = result(angle_free=True)
    out = free.as_dict()
    assert out["target_pose"] == [1e-3, 0.5e-3, None] and out["error_rad"] is None
    _print_result(MoveResult.from_dict(out))
    line = capsys.readouterr().out
    assert "for target (1000.00, 500.00) µm, any angle (error 0.000 µm, any angle)" in line
    faulted = result(status="fault", reached_pose=None).as_dict()
    _print_result(MoveResult.from_dict(faulted))
    assert "(error ?, ?)" in capsys.readouterr().out  # no reached pose: no error, not 0°


@pytest.mark.parametrize("seen", [0.3 + math.pi / 2, 0.3 - 3 * math.pi / 2, 0.3 + math.pi + 1e-4])
def test_the_reached_angle_is_reported_on_the_targets_branch(seen: float) -> None:
    """A square looks the same turned by 90°: 110° seen for a 20° target is 20°."""
    out = result(reached_pose=(1e-3, 0.5e-3, seen)).as_dict()
    assert out["pose"][2] == pytest.approx(0.3 + math.remainder(seen - 0.3, math.pi / 2), abs=1e-12)
    assert abs(out["pose"][2] - 0.3) <= math.pi / 4
    assert out["error_rad"] == pytest.approx(abs(out["pose"][2] - 0.3), abs=1e-12)


class _NoEstimates:
    """What :meth:`MoveRecords.finish` reads of the control loop, with nothing learned."""

    def estimates_json(self) -> dict[str, object]:
        return {}


LOOP: Any = _NoEstimates()


def test_a_pose_move_is_logged_with_its_part_target_and_reached_pose(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    records = MoveRecords(Store(tmp_path / "s.sqlite"), "key", pose_control=True)
    job = Job("move", pose_target={"x_m": 1e-3}, part=2)
    with caplog.at_level("INFO", logger="feeder.daemon.move_records"):
        records.finish(job, result(angle_free=True), LOOP)
    assert caplog.messages[-1] == (
        "move of part 2 done: every part within tolerance (target (0.001, 0.0005) m, any angle, "
        "reached (0.001, 0.0005) m, 0.3 rad, error 0 m / ? rad, 10 steps in 2 bursts)"
    )
    assert caplog.records[-1].levelname == "INFO"


@pytest.mark.parametrize(
    ("status", "level"), [("stopped", "INFO"), ("fault", "WARNING"), ("limit", "WARNING")]
)
def test_a_move_that_did_not_end_as_asked_is_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, status: str, level: str
) -> None:
    """A refused command ended the move ``fault`` with only an INFO line: an operator watching
    warnings (or a journal filtered so) never saw "amplifier refused"."""

    records = MoveRecords(Store(tmp_path / "s.sqlite"), "key", pose_control=True)
    reason = "amplifier refused: Axis in wrong mode" if status == "fault" else status
    with caplog.at_level("INFO", logger="feeder.daemon.move_records"):
        records.finish(
            Job("move", pose_target={"x_m": 1e-3}, part=2), result(status=status, reason=reason), LOOP
        )
    assert caplog.records[-1].levelname == level
    assert f"move of part 2 {status}: {reason} (" in caplog.messages[-1]


def test_the_history_keeps_any_angle_as_null_and_the_reached_angle_on_the_targets_branch(
    tmp_path: Path,
) -> None:
    class Loop:
        reading = ((0.0, 0.0, 0.0), (1e-3, 0.5e-3, 0.2))
        position_m = 0.0

        def estimates_json(self) -> dict[str, object]:
            return {}

    store = Store(tmp_path / "s.sqlite")
    records = MoveRecords(store, "key", pose_control=True)
    free = Job("move", pose_target={"x_m": 1e-3}, part=2)
    free.target_pose, free.target_m, free.angle_free = (1e-3, 0.5e-3, 0.2), 1e-3, True  # as prepare sets
    records.begin(free, Loop())  # type: ignore[arg-type]
    records.finish(free, result(angle_free=True), Loop())  # type: ignore[arg-type]
    turned = Job("move", pose_target={"angle_rad": 0.3}, part=2)
    turned.target_pose, turned.target_m = (1e-3, 0.5e-3, 0.3), 1e-3
    records.begin(turned, Loop())  # type: ignore[arg-type]
    records.finish(turned, result(reached_pose=(1e-3, 0.5e-3, 0.3 + math.pi / 2)), Loop())  # type: ignore[arg-type]
    first, second = store.moves()
    assert first["target_pose"] == [1e-3, 0.5e-3, None]  # was the start angle, as if asked for
    assert second["reached_pose"][2] == pytest.approx(0.3, abs=1e-12)  # a square turned 90° is the same
