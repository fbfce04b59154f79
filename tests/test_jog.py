"""The console's jog in the plane: N learned steps of one axis, each direction with its own step."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

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
    planner = SimpleNamespace(
        model=Model(), turn_per_step=lambda d, pose: Model().turn_step(d, "coarse", *pose).turn_rad
    )
    navigator = PoseNavigator(planner, LoopSettings(), math.pi / 2)  # type: ignore[arg-type]
    return {"axes": navigator.axis_steps(POSE), "parts": [{"id": 1, "pose": list(POSE)}]}


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


def test_a_direction_without_a_learned_step_is_refused() -> None:
    status = plane_status()
    del status["axes"]["x"]["step_back_m"]
    assert jog_request(status, "x", 1, part=1)["x_m"] == pytest.approx(POSE[0] + FORWARD_M)
    with pytest.raises(ApiError) as info:
        jog_request(status, "x", -1, part=1)
    assert info.value.status == 409 and "no learned step of axis x" in str(info.value)
