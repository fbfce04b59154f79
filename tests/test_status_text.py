"""``feeder status`` and ``feeder history`` in the plane, as text: poses, targets, tolerances, steps."""

from __future__ import annotations

import math

from feeder.cli.control import history_line, plane_status_lines
from feeder.daemon.replies import MoveRecord

REPLY = {
    "parts": [
        {"id": 1, "pose": [1e-3, -2e-3, math.radians(30)]},
        {"id": 2, "pose": None},
        {
            "id": 3,
            "pose": [0.0, 1e-3, 0.0],
            "step_rad": math.radians(0.05),
            "step_back_rad": math.radians(0.04),
        },
    ],
    "held": [{"part": 3, "pose": [0.0, 1e-3, None]}],
    "target_part": 1,
    "target_pose": [1.5e-3, -2e-3, None],
    "tolerance_m": 1e-6,
    "tolerance_rad": math.radians(0.1),
    "travel_m": {"x": [-2.5e-3, 2.5e-3], "y": [-1e-3, 1e-3]},
    "axes": {
        "x": {"modes": {}, "step_m": 2e-6, "step_back_m": 3e-6},
        "y": {"modes": {}},
        "theta": {"modes": {}, "step_rad": math.radians(0.5), "step_back_rad": math.radians(0.25)},
    },
}


def test_the_plane_as_text() -> None:
    assert plane_status_lines(REPLY) == [
        "part 1: (1000.00, -2000.00) µm, 30.000°, moving to (1500.00, -2000.00) µm, any angle",
        "part 2: ?",
        "part 3: (0.00, 1000.00) µm, 0.000°, held at (0.00, 1000.00) µm, any angle, "
        "θ step +0.0500° / −0.0400°",
        "tolerance: ±1.000 µm, ±0.100°; travel x [-2500.000 µm, 2500.000 µm]; "
        "travel y [-1000.000 µm, 1000.000 µm]",
        "axis x: coarse step +2.000 µm / −3.000 µm",
        "axis y: coarse step not learned yet",
        "axis theta: turn per step +0.5000° / −0.2500° (part 1's, where it turns)",
    ]


RECORD = {
    "id": 2, "started_s": 0.0, "finished_s": 1.3, "start_m": -6e-4, "target_m": 5e-4, "reached_m": 4.992e-4,
    "error_m": 7.86e-7, "steps": 438, "bursts": 5, "status": "done", "reason": "every part within tolerance",
    "part": 1, "target_pose": [5e-4, 3e-4, math.radians(20)],
    "reached_pose": [4.992e-4, 3e-4, math.radians(20.01)], "error_rad": math.radians(0.01),
}  # fmt: skip


def test_a_pose_move_in_the_history_as_text() -> None:
    assert history_line(MoveRecord.from_dict(RECORD)) == (
        "#2     done        part 1 target (500.00, 300.00) µm, 20.000° reached (499.20, 300.00) µm, 20.010° "
        "error 0.786 µm, 0.0100° steps   438"
    )
    interrupted = {**RECORD, "status": "interrupted", "reason": "daemon killed", "reached_pose": None}
    assert " reached ? error " in history_line(MoveRecord.from_dict(interrupted))
    line = {k: v for k, v in RECORD.items() if k not in ("target_pose", "reached_pose", "error_rad", "part")}
    assert history_line(MoveRecord.from_dict(line)) == (
        "#2     done        target     500.000 µm reached     499.200 µm error    0.786 µm steps   438"
    )
