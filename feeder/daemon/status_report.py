"""The parts of the daemon's ``status`` reply that come from the loop alone: its state and
position, the running move, every part's pose, the axes (waveforms, applied, learned steps), the
plane's travel and tolerances, the step modes' predictions (plain functions of what they read)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from feeder.daemon.control_loop import ControlLoop, Job, StepMode

NOISE_WARNING = 2.0
"""``status`` warns when the sensor's noise seen at rest is over this many times the configured."""


def loop_status(loop: ControlLoop, parts_info: tuple[dict[str, Any], ...]) -> dict[str, Any]:
    """The loop's part of ``status``: state (``fault`` while the amplifier or the sensor is
    lost), position, the running move, holds, the store's writer, estimates, timing, the plane."""
    job = loop.current_job()
    if loop.fault is not None or loop.sensor_lost is not None:
        state = "fault"
    elif job is not None:
        state = "moving" if job.kind == "move" else "calibrating"
    else:
        state = "idle"
    return {
        "state": state,
        "loop_state": loop.state,
        "position_m": loop.position_m,
        "position_state": "uncertain" if loop.position_m is None else "confirmed",
        "target_m": None if job is None else job.target_m,
        **pose_target(job),
        "held": loop.holds(),
        "fault": loop.fault or (None if loop.sensor_lost is None else f"sensor lost: {loop.sensor_lost}"),
        "store_unwritable": loop.writer.unwritable,
        "pending_records": loop.writer.pending(),
        "records_dropped": loop.writer.dropped,
        "record_dropped_reason": loop.writer.dropped_reason,
        "tolerance_m": loop.settings.tolerance_m,
        "travel_limits_m": [loop.settings.min_position_m, loop.settings.max_position_m],
        "estimates": loop.estimates_json(),
        **plane_status(loop, parts_info),
        "timing": loop.timing(),
        "sensor_latency_s": loop.policy.latency_s,
        **sensor_noise(loop.policy.resting_noise.sigma_m, loop.settings.sensor_noise_m),
        "last_result": None if loop.last_result is None else loop.last_result.as_dict(),
    }


def sensor_noise(seen_m: float | None, configured_m: float) -> dict[str, Any]:
    """The sensor's noise as configured (``[control] sensor_noise_m``) and as seen while the parts
    were at rest (:class:`~feeder.reading_noise.RestingNoise`; None before enough readings), and
    a warning when the one seen is over :data:`NOISE_WARNING` × the configured."""
    warning = None
    if seen_m is not None and seen_m > NOISE_WARNING * configured_m:
        warning = (
            f"the sensor's readings of parts at rest scatter {seen_m * 1e6:.3g} µm (1σ), over "
            f"{NOISE_WARNING:g} × [control] sensor_noise_m = {configured_m * 1e6:.3g} µm: the settle "
            "band, the stall test and the step learning assume the configured value; set it"
        )
    return {"sensor_noise_m": configured_m, "sensor_noise_seen_m": seen_m, "sensor_noise_warning": warning}


def plane_status(loop: ControlLoop, parts_info: tuple[dict[str, Any], ...]) -> dict[str, Any]:
    """Every part's pose, the axes and the plane's travel and tolerances (pose control);
    ``parts_info``: each part's ``shape`` and ``size_m`` (empty: one part, nothing known)."""
    reading = loop.reading or ()
    s = loop.settings
    steps_of = getattr(loop.policy.navigator, "axis_steps", None)
    parts = []
    learned: dict[str, dict[str, float]] = {}  # the axes' steps: part 1's (θ's where it turns)
    for i, info in enumerate(parts_info or ({"id": 1},), start=1):
        pose = reading[i - 1] if i <= len(reading) else None
        steps = steps_of(pose) if callable(steps_of) and (pose is not None or i == 1) else {}
        if i == 1:
            learned = steps
        # θ's step depends on where the part is: each part's own (what its jog moves by)
        turns = steps.get("theta", {}) if pose is not None else {}
        parts.append({**info, "id": i, "pose": None if pose is None else list(pose), **turns})
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
        "symmetry_rad": getattr(loop.policy.navigator, "symmetry_rad", None),
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
