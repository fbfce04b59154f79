"""The console's jog in the plane: N learned steps of one axis, each direction with its own step."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from feeder.daemon import status_report
from feeder.daemon.jobs import LoopSettings
from feeder.daemon.pose_navigator import PoseNavigator
from feeder.web.requests import ApiError, jog_request

FORWARD_M, BACK_M = 2e-6, 3e-6
FORWARD_RAD, BACK_RAD = 1e-3, 2e-3
POSE = (1e-3, -0.5e-3, 0.2)


class Model:
    """A learned response whose two directions differ (as the demo's do: ×0.47 and ×0.81)."""

    def step_m(self, axis: str, direction: int, mode: str) -> tuple[float, float]:
        return (FORWARD_M if direction > 0 else BACK_M), 0.1e-6

    def modes(self, axis: str) -> tuple[str, ...]:
        return ("coarse", "fine")

    def turn_step(self, direction: int, mode: str, x: float, y: float, psi: float) -> SimpleNamespace:
        return SimpleNamespace(turn_rad=direction * (FORWARD_RAD if direction > 0 else BACK_RAD))


def plane_status() -> dict:
    turns = SimpleNamespace(turn_per_step=lambda d, pose: Model().turn_step(d, "coarse", *pose).turn_rad)
    planner = SimpleNamespace(model=Model(), turns=turns)
    navigator = PoseNavigator(planner, LoopSettings(), math.pi / 2)  # type: ignore[arg-type]
    steps = navigator.axis_steps(POSE)
    return {"axes": steps, "parts": [{"id": 1, "pose": list(POSE), **steps["theta"]}]}


def test_the_status_reports_each_axis_step_in_both_directions() -> None:
    assert plane_status()["axes"] == {
        "x": {"step_m": FORWARD_M, "step_back_m": BACK_M},
        "y": {"step_m": FORWARD_M, "step_back_m": BACK_M},
        "theta": {"step_rad": FORWARD_RAD, "step_back_rad": BACK_RAD},
    }


@pytest.mark.parametrize(
    ("axis", "steps", "field", "expected"),
    [
        ("x", 5, "x_m", POSE[0] + 5 * FORWARD_M),
        ("x", -5, "x_m", POSE[0] - 5 * BACK_M),
        ("y", -2, "y_m", POSE[1] - 2 * BACK_M),
        ("theta", 3, "angle_rad", POSE[2] + 3 * FORWARD_RAD),
        ("theta", -3, "angle_rad", POSE[2] - 3 * BACK_RAD),
    ],
)
def test_a_jog_moves_by_the_step_learned_in_its_direction(
    axis: str, steps: int, field: str, expected: float
) -> None:
    request = jog_request(plane_status(), axis, steps, part=1)
    assert request == {"cmd": "move", "part": 1, field: pytest.approx(expected, rel=1e-12), "wait": False}


def test_a_turn_jog_moves_by_the_jogged_parts_own_step() -> None:
    """θ's step depends on where the part is (none in the dead zone at O, larger far out):
    part 2's jog moved by part 1's step until 2026-11-27."""
    status = plane_status()
    status["parts"].append({"id": 2, "pose": [0.0, 2e-3, 0.1], "step_rad": 5e-3, "step_back_rad": 4e-3})
    assert jog_request(status, "theta", 2, part=2)["angle_rad"] == pytest.approx(0.1 + 2 * 5e-3)
    assert jog_request(status, "theta", -2, part=2)["angle_rad"] == pytest.approx(0.1 - 2 * 4e-3)
    assert jog_request(status, "theta", 2, part=1)["angle_rad"] == pytest.approx(POSE[2] + 2 * FORWARD_RAD)
    status["parts"].append({"id": 3, "pose": [0.0, 0.0, 0.0]})  # no θ mode turns it anywhere
    with pytest.raises(ApiError) as info:
        jog_request(status, "theta", 1, part=3)
    assert info.value.status == 409 and "no learned step of axis theta" in str(info.value)


def test_the_status_gives_each_part_its_own_turn_step() -> None:
    """status_report.plane_status asks the navigator for each part's θ step at its pose."""
    turn_at = {(1e-3, 0.0): 2e-3, (3e-3, 0.0): 7e-3}
    navigator = SimpleNamespace(
        axis_steps=lambda pose: (
            {}
            if pose is None
            else {"theta": {"step_rad": turn_at[pose[:2]], "step_back_rad": turn_at[pose[:2]] / 2}}
        )
    )
    loop = SimpleNamespace(
        reading=((1e-3, 0.0, 0.0), (3e-3, 0.0, 0.5)),
        settings=LoopSettings(),
        policy=SimpleNamespace(navigator=navigator, modes={}, applied=lambda axis: None),
    )
    parts = status_report.plane_status(loop, ({"shape": "rect"}, {"shape": "rect"}))["parts"]  # type: ignore[arg-type]
    assert [(p["id"], p["step_rad"], p["step_back_rad"]) for p in parts] == [
        (1, 2e-3, 1e-3),
        (2, 7e-3, 3.5e-3),
    ]


def test_a_direction_without_a_learned_step_is_refused() -> None:
    status = plane_status()
    del status["axes"]["x"]["step_back_m"]
    assert jog_request(status, "x", 1, part=1)["x_m"] == pytest.approx(POSE[0] + FORWARD_M)
    with pytest.raises(ApiError) as info:
        jog_request(status, "x", -1, part=1)
    assert info.value.status == 409 and "no learned step of axis x" in str(info.value)


def test_a_jog_within_the_tolerance_is_refused_saying_how_many_steps_would_move() -> None:
    """The daemon finds a part already within the tolerance of such a target and takes no step:
    a θ jog of one fine step at O ended "done" with nothing moved."""
    status = {**plane_status(), "tolerance_m": 5e-6, "tolerance_rad": 2.5e-3}
    for axis, steps, least in (("x", 2, 3), ("y", -1, 2), ("theta", 2, 3), ("theta", -1, 2)):
        with pytest.raises(ApiError) as info:
            jog_request(status, axis, steps, part=1)
        assert info.value.status == 409, axis
        assert "within the tolerance" in str(info.value) and f"jog at least {least} steps" in str(info.value)
        moved = jog_request(status, axis, least if steps > 0 else -least, part=1)
        assert moved["cmd"] == "move" and moved["part"] == 1
    one_axis = {"axes": {"x": {}}, "estimates": {"coarse/forward": {"step_m": 2e-6}}, "tolerance_m": 5e-6}
    with pytest.raises(ApiError) as info:
        jog_request(one_axis, "x", 2, part=1)
    assert str(info.value) == (
        "2 step(s) of axis x move by 4 µm, within the tolerance (5 µm): nothing would move; "
        "jog at least 3 steps"
    )
    assert jog_request(one_axis, "x", 3, part=1)["by_m"] == pytest.approx(6e-6)


def test_a_turn_jog_of_half_the_symmetry_or_beyond_one_turn_is_bad_input() -> None:
    """10000 θ steps of a square at O asked for +4.29 rad: accepted, the square turned −24.3°
    (the same pose modulo 90°, the shorter way); a disc's jog beyond one turn got the daemon's
    409.  Both are bad input (400), saying how many steps a jog may take."""
    status = {**plane_status(), "symmetry_rad": math.pi / 2}
    assert jog_request(status, "theta", 785, part=1)["angle_rad"] == pytest.approx(POSE[2] + 0.785)
    with pytest.raises(ApiError) as info:
        jog_request(status, "theta", 786, part=1)  # 45.03°
    assert (
        info.value.status == 400 and "every 90°" in str(info.value) and "at most 785 steps" in str(info.value)
    )
    with pytest.raises(ApiError) as info:
        jog_request(status, "theta", -393, part=1)  # 2e-3 rad back each: 45.04°
    assert info.value.status == 400 and "at most 392 steps" in str(info.value)
    disc = {**plane_status(), "symmetry_rad": 0.0}
    assert jog_request(disc, "theta", 6000, part=1)["angle_rad"] == pytest.approx(POSE[2] + 6.0)
    with pytest.raises(ApiError) as info:
        jog_request(disc, "theta", 7000, part=1)
    assert info.value.status == 400 and "beyond one turn" in str(info.value)
