"""The parts of the daemon's ``status`` reply that come from the loop alone: every part's pose,
the axes (waveforms, applied, learned steps), the plane's travel and tolerances, the running pose
move's target, the step modes' predictions (plain functions of what they read)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from feeder.daemon.control_loop import ControlLoop, Job, StepMode


def plane_status(loop: ControlLoop, parts_info: tuple[dict[str, Any], ...]) -> dict[str, Any]:
    """Every part's pose, the axes and the plane's travel and tolerances (pose control);
    ``parts_info``: each part's ``shape`` and ``size_m`` (empty: one part, nothing known)."""
    reading = loop.reading or ()
    s = loop.settings
    parts = []
    for i, info in enumerate(parts_info or ({"id": 1},), start=1):
        pose = reading[i - 1] if i <= len(reading) else None
        parts.append({**info, "id": i, "pose": None if pose is None else list(pose)})
    steps_of = getattr(loop.policy.navigator, "axis_steps", None)
    learned = steps_of(reading[0] if reading else None) if callable(steps_of) else {}
    return {
        "parts": parts,
        "axes": {
            axis: {
                "modes": {k: dataclasses.asdict(m.settings) for k, m in modes.items()},
                "applied": loop.policy.applied(axis),
                **learned.get(axis, {}),
            }
            for axis, modes in loop.policy.modes.items()
        },
        "tolerance_rad": s.tolerance_rad,
        "travel_m": {"x": [s.min_position_m, s.max_position_m], "y": [s.min_y_m, s.max_y_m]},
    }


def pose_target(job: Job | None) -> dict[str, Any]:
    """The running pose move's part and target [x_m, y_m, psi_rad] (None: "any angle"), or nothing."""
    if job is None or job.target_pose is None:
        return {}
    x, y, psi = job.target_pose
    return {"target_part": job.part, "target_pose": [x, y, None if job.angle_free else psi]}


def waveforms_status(modes: Mapping[str, StepMode]) -> dict[str, Any]:
    """The x axis' step modes: each one's predicted step (m) and waveform with its band."""
    return {
        "predicted_steps_m": {k: m.predicted_step_m for k, m in modes.items()},
        "waveforms": {
            k: {**dataclasses.asdict(m.settings), "predicted_step_band_m": list(m.predicted_band_m)}
            for k, m in modes.items()
        },
    }
