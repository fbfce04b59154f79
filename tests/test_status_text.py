"""``feeder status`` in the plane, as text: poses, the running move's target, tolerances, steps."""

from __future__ import annotations

import math

from feeder.cli.control import plane_status_lines

REPLY = {
    "parts": [{"id": 1, "pose": [1e-3, -2e-3, math.radians(30)]}, {"id": 2, "pose": None}],
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
        "tolerance: ±1.000 µm, ±0.100°; travel x [-2500.000 µm, 2500.000 µm]; "
        "travel y [-1000.000 µm, 1000.000 µm]",
        "axis x: coarse step +2.000 µm / −3.000 µm",
        "axis y: coarse step not learned yet",
        "axis theta: coarse step +0.5000° / −0.2500° (part 1's turn where it is)",
    ]
