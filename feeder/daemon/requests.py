"""The socket's requests: each ``cmd``'s fields checked, its job built, its reply composed.

:func:`answer` takes one request object (see :mod:`feeder.daemon.client`) and answers it
through the :class:`~feeder.daemon.service.Daemon`'s public methods, which run, queue and
stop the jobs; nothing here takes a daemon lock.  A refused request is answered
``{"ok": false, "error": reason}``, and so is, before anything starts, a field its ``cmd`` does
not know (:data:`FIELDS`) or a flag that is not true or false.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from feeder.daemon.calibration import CALIBRATION_STEPS, calibration_bursts, calibration_room, fine_steps_for
from feeder.daemon.control_loop import COARSE, Burst, Job
from feeder.daemon.request_fields import RequestFieldError, check_known, finite, flag, integer
from feeder.daemon.step_estimator import FORWARD
from feeder.errors import FeederError

if TYPE_CHECKING:
    from feeder.daemon.service import Daemon

log = logging.getLogger(__name__)

PLANE_CALIBRATE = (
    "calibrate is the one-axis daemon's job (--line): on the plane every burst of a move "
    "teaches the pose model its x, y and θ steps"
)

POSE_KEYS = ("x_m", "y_m", "angle_rad")
"""A pose move's target, any subset (m, m, rad; plate frame)."""
JOB_FLAGS = ("queue", "wait", "trace")
"""A move's and a calibration's flags (:func:`_job_flags`)."""
FIELDS: dict[str, frozenset[str]] = {
    "move": frozenset({"cmd", "target_m", "by_m", *POSE_KEYS, "part", *JOB_FLAGS}),
    "calibrate": frozenset({"cmd", "steps", *JOB_FLAGS}),
    "calibrate_camera": frozenset(
        {"cmd", "volts", "stack_gain_m_per_v", "increment_v", "frames", "slip_fraction", "save"}
    ),
    "stop": frozenset({"cmd"}),
    "status": frozenset({"cmd"}),
    "history": frozenset({"cmd", "limit"}),
    "release": frozenset({"cmd", "part"}),
    "shutdown": frozenset({"cmd"}),
}
"""Each ``cmd``'s fields; any other is refused (a misspelt ``wait`` ran a waiting move, a
misspelt ``part`` moved part 1), except by ``stop``, which stops all the same (and logs it)."""


def answer(daemon: Daemon, request: Any, hung_up: Callable[[], bool] = lambda: False) -> dict[str, Any]:
    """The reply to one request object: its ``cmd``'s, or why there is none.  ``hung_up``:
    whether the client has gone (a camera calibration then stops: no one would read it)."""
    if not isinstance(request, dict):
        return {"ok": False, "error": "a request must be a JSON object"}
    cmd = request.get("cmd")
    if not isinstance(cmd, str) or cmd not in COMMANDS:
        return {"ok": False, "error": f"unknown cmd {cmd!r}; known: {', '.join(COMMANDS)}"}
    try:
        check_known(request, FIELDS[cmd])
    except RequestFieldError as err:
        if cmd != "stop":  # a stop acts whatever else it carries: nothing may keep it from the daemon
            return {"ok": False, "error": str(err)}
        log.warning("stop: %s (stopped all the same)", err)
    if cmd in _UNTIL_HANG_UP:
        return _UNTIL_HANG_UP[cmd](daemon, request, hung_up)
    return _COMMANDS[cmd](daemon, request)


def _new_job(
    daemon: Daemon,
    kind: str,
    target_m: float | None,
    by_m: float | None,
    bursts: tuple[Burst, ...] = (),
    *,
    pose_target: dict[str, float] | None = None,
    part: int = 1,
) -> Job:
    """A job that the daemon's move records follow from its start to its result."""
    job = Job(kind, target_m=target_m, by_m=by_m, bursts=bursts, pose_target=pose_target, part=part)
    job.on_start = lambda: daemon.records.begin(job, daemon.loop)
    job.on_done = lambda result: daemon.records.finish(job, result, daemon.loop)
    job.on_progress = lambda: daemon.records.progress(job)
    return job


def _job_flags(request: dict[str, Any]) -> tuple[bool, bool, bool]:
    """The request's ``queue``, ``wait`` and ``trace`` (:func:`_run_job`), each true or false."""
    return flag(request, "queue", False), flag(request, "wait", True), flag(request, "trace", False)


def _run_job(daemon: Daemon, job: Job, flags: tuple[bool, bool, bool]) -> dict[str, Any]:
    """Run ``job`` (queued with ``queue``); its result (with its ``trace``), or with ``wait``
    false only that it was accepted."""
    queue, wait, trace = flags
    position, reason = daemon.run(job, queue=queue)
    if reason is not None:
        return {"ok": False, "error": reason}
    if not wait:
        return {"ok": True, "accepted": True, "queue_position": position}
    job.done.wait()
    assert job.result is not None
    result = job.result.as_dict(with_trace=trace)
    result["move_id"] = job.record_id
    ok = job.result.status == "done"
    return {"ok": ok, "result": result, **({} if ok else {"error": job.result.reason})}


def _move(daemon: Daemon, request: dict[str, Any]) -> dict[str, Any]:
    try:
        target = finite(request, "target_m")
        by = finite(request, "by_m")
        pose = {k: v for k in POSE_KEYS if (v := finite(request, k)) is not None}
        part = integer(request, "part", 1, 1)
        flags = _job_flags(request)
    except RequestFieldError as err:
        return {"ok": False, "error": str(err)}
    if pose:
        if target is not None or by is not None:
            return {"ok": False, "error": "give a pose (x_m, y_m, angle_rad) or target_m/by_m, not both"}
        if daemon.setup.pose_navigator is not None:
            return _run_job(daemon, _new_job(daemon, "move", None, None, pose_target=pose, part=part), flags)
        if set(pose) != {"x_m"}:
            return {"ok": False, "error": "this configuration drives one axis (x): give x_m or target_m"}
        target = pose["x_m"]
    if (target is None) == (by is None):
        return {
            "ok": False,
            "error": "give exactly one of target_m and by_m, or a pose (x_m, y_m, angle_rad)",
        }
    return _run_job(daemon, _new_job(daemon, "move", target, by, part=part), flags)


def _calibrate(daemon: Daemon, request: dict[str, Any]) -> dict[str, Any]:
    if daemon.setup.pose_navigator is not None:
        return {"ok": False, "error": PLANE_CALIBRATE}
    try:
        steps = integer(request, "steps", CALIBRATION_STEPS, 2, 10_000)
        flags = _job_flags(request)
    except RequestFieldError as err:
        return {"ok": False, "error": str(err)}
    allowed = _calibration_room(daemon)
    if isinstance(allowed, str):
        return {"ok": False, "error": allowed}
    limited = steps > allowed
    steps = min(steps, allowed)
    fine_steps = fine_steps_for(steps, daemon.setup.modes)
    reply = _run_job(
        daemon, _new_job(daemon, "calibrate", None, None, calibration_bursts(steps, fine_steps)), flags
    )
    if limited:
        reply["note"] = (
            f"calibration limited to {steps} coarse steps per direction by the "
            "travel left on either side of the part"
        )
    reply["calibration_steps"] = steps
    return reply


def _calibration_room(daemon: Daemon) -> int | str:
    """:func:`.calibration_room` from where the part is (waiting up to the sensor timeout for a
    first reading); a reason string when there is no room or no position."""
    deadline = time.monotonic() + daemon.setup.sensor_timeout_s
    while daemon.loop.position_m is None and time.monotonic() < deadline:
        time.sleep(0.01)  # just started: the first frame is on its way
    x = daemon.loop.position_m
    if x is None:
        return "position uncertain: calibration needs a sensor reading first"
    estimate = daemon.loop.estimates()[f"{COARSE}/{FORWARD}"]
    return calibration_room(x, daemon.loop.settings, estimate, daemon.setup.modes[COARSE].predicted_band_m[1])


def _calibrate_camera(daemon: Daemon, request: dict[str, Any], hung_up: Callable[[], bool]) -> dict[str, Any]:
    """The camera's calibration from plate moves (:mod:`~feeder.daemon.camera_moves`): the
    report, stored with ``"save": true``; answered when the moves end (~1 min), stopped
    (grounded, nothing stored) when the client hangs up meanwhile."""
    plate = daemon.setup.plate_moves
    if plate is None:
        return {"ok": False, "error": "the plate moves calibrate the camera of a plane (x, y, θ; a camera)"}
    try:
        save = flag(request, "save", False)
        moves = plate.moves(request)
        report = daemon.camera_moves(moves, save, hung_up)
    except FeederError as err:  # a refused field, a refusal, a stop or a device's error
        return {"ok": False, "error": str(err)}
    return {"ok": True, "calibration": {**report, "image_px": list(plate.image_px)}}


def _stop(daemon: Daemon, request: dict[str, Any]) -> dict[str, Any]:
    stopped, dequeued = daemon.stop()
    return {"ok": True, "stopped": stopped, "dequeued": dequeued}


def _release(daemon: Daemon, request: dict[str, Any]) -> dict[str, Any]:
    """Let held parts go: ``part`` N, or every part when absent (the plane; one axis holds none)."""
    try:
        part = None if request.get("part") is None else integer(request, "part", 1, 1)
    except RequestFieldError as err:
        return {"ok": False, "error": str(err)}
    released = daemon.loop.release(part)
    if isinstance(released, str):
        return {"ok": False, "error": released}
    return {"ok": True, "released": released}


def _history(daemon: Daemon, request: dict[str, Any]) -> dict[str, Any]:
    try:
        limit = integer(request, "limit", 100, 1, 100_000)
    except RequestFieldError as err:
        return {"ok": False, "error": str(err)}
    return {"ok": True, "moves": daemon.store.moves(limit)}


def _shutdown(daemon: Daemon, request: dict[str, Any]) -> dict[str, Any]:
    threading.Thread(target=daemon.shutdown, name="shutdown", daemon=True).start()
    return {"ok": True, "shutting_down": True}


def _status(daemon: Daemon, request: dict[str, Any]) -> dict[str, Any]:
    return {"ok": True, **daemon.status()}


_COMMANDS: dict[str, Callable[[Daemon, dict[str, Any]], dict[str, Any]]] = {
    "move": _move,
    "stop": _stop,
    "status": _status,
    "calibrate": _calibrate,
    "history": _history,
    "release": _release,
    "shutdown": _shutdown,
}
"""The requests answered whatever the client does meanwhile (a move runs on when its client goes)."""
_UNTIL_HANG_UP: dict[str, Callable[[Daemon, dict[str, Any], Callable[[], bool]], dict[str, Any]]] = {
    "calibrate_camera": _calibrate_camera,
}
"""The requests that stop when their client hangs up (no one would read their result)."""
COMMANDS = (*_COMMANDS, *_UNTIL_HANG_UP)
"""Every ``cmd``, in the order the unknown-cmd error lists them."""
