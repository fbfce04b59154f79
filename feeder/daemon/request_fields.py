"""The fields of a client's request object (:mod:`feeder.daemon.client`), checked.

Each reader returns the field's value or raises :class:`RequestFieldError`,
whose message is the reply's ``error``: it names the field and what arrived
(cut short by :func:`brief`).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Collection
from typing import Any

from feeder.errors import FeederError


class RequestFieldError(FeederError):
    """A request field is missing its type or range; ``str(err)`` names it."""


class FieldRangeError(RequestFieldError):
    """A request field is a number of the right type, outside its range."""


def brief(value: Any) -> str:
    """``repr`` of a request value, cut short (a 4000-digit integer is no error message)."""
    try:
        text = repr(value)
    except ValueError:  # an integer beyond the digit limit of str()
        return f"<{type(value).__name__} too large to print>"
    return text if len(text) <= 40 else text[:37] + "..."


ONE_TURN_RAD = 2 * math.pi
"""A pose's ``angle_rad`` lies within ± this (1e18 rad had the plate turn for 40 s; 400 is
degrees meant as radians)."""


UNITS = (("_rad", "radians"), ("_m_per_v", "m/V"), ("_v", "volts"), ("volts", "volts"), ("", "metres"))
"""A field's unit by the end of its name (the first that fits)."""


def finite(request: dict[str, Any], key: str) -> float | None:
    """``request[key]`` as a finite number (its unit by its name: :data:`UNITS`; ``angle_rad``
    within ±:data:`ONE_TURN_RAD`); None when absent."""
    value = request.get(key)
    if value is None:
        return None
    try:
        number = float(value) if not isinstance(value, bool) else math.nan
    except (TypeError, ValueError, OverflowError):
        number = math.nan
    if not isinstance(value, (int, float)) or not math.isfinite(number):
        unit = next(name for suffix, name in UNITS if key.endswith(suffix))
        raise RequestFieldError(f"{key} must be a finite number of {unit}, got {brief(value)}")
    wrong = beyond_one_turn(number) if key == "angle_rad" else None
    if wrong is not None:
        raise FieldRangeError(wrong)
    return number


def beyond_one_turn(angle_rad: float) -> str | None:
    """Why ``angle_rad`` is no pose's angle (beyond ±:data:`ONE_TURN_RAD`), or None."""
    if abs(angle_rad) > ONE_TURN_RAD:
        return f"angle_rad must lie within ±2π (one turn), got {angle_rad:.6g} (radians, not degrees?)"
    return None


def integer(request: dict[str, Any], key: str, default: int, low: int, high: int | None = None) -> int:
    """``request[key]`` as an integer in [low, high] (no upper bound: None); ``default`` when absent."""
    value = request.get(key, default)
    whole = isinstance(value, int) and not isinstance(value, bool)
    if not whole or value < low or (high is not None and value > high):
        bounds = f">= {low}" if high is None else f"in [{low}, {high}]"
        raise RequestFieldError(f"{key} must be an integer {bounds}, got {brief(value)}")
    return value


def flag(request: dict[str, Any], key: str, default: bool) -> bool:
    """``request[key]`` as true or false (``"false"``, 0 or null are refused); ``default`` when absent."""
    value = request.get(key, default)
    if not isinstance(value, bool):
        raise RequestFieldError(f"{key} must be true or false, got {brief(value)}")
    return value


def check_known(request: dict[str, Any], known: Collection[str]) -> None:
    """Refuse the request's first field not in ``known``, naming it (and the nearest known one,
    if one is close): a misspelt ``wait`` or ``part`` must not fall back to its default."""
    unknown = next((key for key in request if key not in known), None)
    if unknown is None:
        return
    names = sorted(known)
    near = difflib.get_close_matches(unknown, names, n=1)
    hint = f"; did you mean {near[0]!r}?" if near else ""
    raise RequestFieldError(f"unknown field {brief(unknown)}; known: {', '.join(names)}{hint}")
