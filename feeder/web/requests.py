"""What the console's API accepts: JSON bodies with their field types checked, a jog turned
into a move; a refusal is ``{"ok": false, "error": ...}`` with a 4xx code."""

from __future__ import annotations

import json
import math
from typing import Any

from starlette.requests import ClientDisconnect, Request
from starlette.responses import JSONResponse

from feeder.daemon.client_connection import MAX_LINE_BYTES
from feeder.daemon.request_fields import FieldRangeError, RequestFieldError, beyond_one_turn, finite
from feeder.errors import FeederError

MAX_JOG_STEPS = 10_000


class ApiError(FeederError):
    """A request refused with an HTTP status and a one-line reason."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


def error_response(status: int, message: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"ok": False, "error": message}, status_code=status, headers=headers)


async def json_body(request: Request) -> dict[str, Any]:
    """The body as a JSON object (empty body: ``{}``); 413/400 otherwise."""
    raw = bytearray()
    try:
        async for chunk in request.stream():
            raw += chunk
            if len(raw) > MAX_LINE_BYTES:
                raise ApiError(413, f"request body longer than {MAX_LINE_BYTES} bytes")
    except ClientDisconnect:  # closed mid-body (or cut for sending it too slowly): nothing to do
        raise ApiError(400, "the connection closed before the whole body arrived") from None
    if not raw.strip():
        return {}
    try:
        body = json.loads(bytes(raw))
    except (ValueError, RecursionError) as err:
        raise ApiError(400, f"malformed JSON: {type(err).__name__}: {str(err)[:200]}") from None
    if not isinstance(body, dict):
        raise ApiError(400, f"the body must be a JSON object, got {type(body).__name__}")
    return body


NUMBERS = frozenset(
    {
        "target_m",
        "by_m",
        "x_m",
        "y_m",
        "angle_rad",
        "volts",
        "stack_gain_m_per_v",
        "increment_v",
        "slip_fraction",
    }
)
FLAGS = frozenset({"queue", "wait", "trace", "save"})
INTEGERS = frozenset({"part", "steps", "frames"})
FIELDS = {
    "move": frozenset({"target_m", "by_m", "x_m", "y_m", "angle_rad", "queue", "wait", "trace", "part"}),
    "calibrate": frozenset({"queue", "wait", "trace", "steps"}),
    "calibrate_camera": frozenset(
        {"volts", "stack_gain_m_per_v", "increment_v", "frames", "slip_fraction", "save"}
    ),
    "release": frozenset({"part"}),
    "jog": frozenset({"axis", "steps", "part"}),
}


def _brief(value: Any) -> str:
    """The JSON of a refused value, cut short (a 4000-digit integer is no error message)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value).bit_length() > 128:
        return f"an integer of {abs(value).bit_length()} bits"
    return json.dumps(value)[:40]


def checked(cmd: str, body: dict[str, Any]) -> dict[str, Any]:
    """``body`` with its field types checked (the daemon checks ranges and combinations)."""
    for key, value in body.items():
        if key not in FIELDS[cmd]:
            known = ", ".join(sorted(FIELDS[cmd])) or "none"
            raise ApiError(400, f"unknown field {key!r} for {cmd}; known: {known}")
        if key in NUMBERS:
            try:  # the daemon's own check (an integer beyond a float's range fails); null is none
                number = finite(body, key)
            except FieldRangeError as err:
                raise ApiError(400, str(err)) from None
            except RequestFieldError:
                number = None
            if number is None:
                raise ApiError(400, f"{key} must be a finite number, got {_brief(value)}")
        if key in FLAGS and not isinstance(value, bool):
            raise ApiError(400, f"{key} must be true or false")
        if key in INTEGERS and (isinstance(value, bool) or not isinstance(value, int)):
            raise ApiError(400, f"{key} must be an integer")
        if key == "part" and value < 1:
            raise ApiError(400, f"part must be a part id ≥ 1, got {_brief(value)}")
    given = [
        group for group in (("target_m",), ("by_m",), ("x_m", "y_m", "angle_rad")) if set(group) & set(body)
    ]
    if cmd == "move" and len(given) > 1:
        raise ApiError(400, "give exactly one of target_m and by_m, or a pose (x_m, y_m, angle_rad)")
    return body


def jog_request(status: dict[str, Any], axis: str, steps: int, part: int) -> dict[str, Any]:
    """The move request for ``steps`` learned steps (sign = direction) of ``axis``.

    On a plane (more than one axis in the status' ``axes``): the part's pose plus ``steps`` ×
    the axis' learned step in that direction (``axes[axis]["step_m"]`` forward,
    ``["step_back_m"]`` back; for theta the part's own ``step_rad`` and ``step_back_rad`` in
    ``parts``: a turn depends on where the part is); on one axis: ``by_m``, with the coarse
    step learned in that direction.
    """
    if not 0 < abs(steps) <= MAX_JOG_STEPS:
        raise ApiError(400, f"steps must be a non-zero integer within ±{MAX_JOG_STEPS}, got {_brief(steps)}")
    parts = [p for p in status.get("parts") or () if p.get("pose") is not None]
    if len(status.get("axes") or ()) <= 1:  # one axis: today's feeder
        if axis != "x":
            raise ApiError(409, f"this daemon drives one axis (x); there is no {axis!r} to jog")
        name = "coarse/forward" if steps > 0 else "coarse/backward"
        step = status.get("estimates", {}).get(name, {}).get("step_m")
        if not isinstance(step, (int, float)):
            raise ApiError(409, "no learned step to jog with")
        _check_beyond_tolerance(status.get("tolerance_m"), axis, steps, step)
        return {"cmd": "move", "by_m": steps * step, "wait": False}
    axes = status.get("axes") or {}
    if axis not in axes:
        raise ApiError(400, f"axis must be one of {', '.join(axes)}, got {axis!r}")
    entry = next((p for p in parts if p.get("id") == part), None)
    if entry is None:
        raise ApiError(400, f"no part {part}; parts: {', '.join(str(p.get('id')) for p in parts)}")
    pose = entry["pose"]
    key, index, field = {"x": ("step_m", 0, "x_m"), "y": ("step_m", 1, "y_m")}.get(
        axis, ("step_rad", 2, "angle_rad")
    )
    if steps < 0:
        key = key.replace("step_", "step_back_")
    learned = entry if axis == "theta" else axes[axis]
    step = learned.get(key) if isinstance(learned, dict) else None
    if not isinstance(step, (int, float)):
        raise ApiError(409, f"no learned step of axis {axis} to jog with")
    _check_beyond_tolerance(
        status.get("tolerance_rad" if axis == "theta" else "tolerance_m"), axis, steps, step
    )
    value = pose[index] + steps * step
    if axis == "theta":
        _check_within_symmetry(status.get("symmetry_rad"), steps, step)
        wrong = beyond_one_turn(value)
        if wrong is not None:
            raise ApiError(400, f"{abs(steps)} steps of axis theta ask for an angle beyond one turn: {wrong}")
    return {"cmd": "move", "part": part, field: value, "wait": False}


def _check_within_symmetry(symmetry_rad: Any, steps: int, step: float) -> None:
    """Refuse a θ jog of half the part's symmetry or more (400): the camera sees the angle modulo
    it, so the daemon turns the shorter way (10000 steps at O asked for +4.29 rad and turned a
    square by −24.3°)."""
    if isinstance(symmetry_rad, (int, float)) and symmetry_rad > 0 and abs(steps * step) >= symmetry_rad / 2:
        most = math.ceil(symmetry_rad / 2 / abs(step)) - 1
        raise ApiError(
            400,
            f"{abs(steps)} steps of axis theta turn by {math.degrees(abs(steps * step)):.3g}°, but the part "
            f"looks the same every {math.degrees(symmetry_rad):.3g}°: a jog turns by less than half that "
            f"(at most {most} steps here)",
        )


def _check_beyond_tolerance(tolerance: Any, axis: str, steps: int, step: float) -> None:
    """Refuse a jog that asks for no more than the tolerance (m, or rad for θ): the daemon would
    find the part already there and take no step (a θ jog of 1 fine step at O, 0.05°, ended
    "done" with nothing moved)."""
    if not isinstance(tolerance, (int, float)) or abs(steps * step) > tolerance:
        return

    def shown(v: float) -> str:
        return f"{math.degrees(v):.3g}°" if axis == "theta" else f"{v * 1e6:.3g} µm"

    asked = f"{abs(steps)} step(s) of axis {axis} move by {shown(abs(steps * step))}"
    least = f"; jog at least {math.floor(tolerance / abs(step)) + 1} steps" if step else ""
    raise ApiError(409, f"{asked}, within the tolerance ({shown(tolerance)}): nothing would move{least}")
