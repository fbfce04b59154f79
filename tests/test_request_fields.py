"""The daemon's request fields: what each reader accepts, and the one-line error for the rest."""

from __future__ import annotations

import pytest

from feeder.daemon.request_fields import FieldRangeError, RequestFieldError, brief, finite, integer
from feeder.errors import FeederError


@pytest.mark.parametrize("value", [1, -2.5e-4, 0, 10**300])
def test_finite_accepts_numbers(value: float) -> None:
    assert finite({"x_m": value}, "x_m") == float(value)


def test_finite_absent_is_none() -> None:
    assert finite({}, "x_m") is None
    assert finite({"x_m": None}, "x_m") is None


@pytest.mark.parametrize(
    ("value", "shown"),
    [
        (True, "True"),
        (float("nan"), "nan"),
        (float("inf"), "inf"),
        ("1e-3", "'1e-3'"),
        ([1], "[1]"),
        (10**400, "1000000000000000000000000000000000000..."),
    ],
)
def test_finite_refuses_and_names_the_field(value: object, shown: str) -> None:
    with pytest.raises(RequestFieldError) as err:
        finite({"angle_rad": value}, "angle_rad")
    assert str(err.value) == f"angle_rad must be a finite number of radians, got {shown}"
    assert isinstance(err.value, FeederError)


@pytest.mark.parametrize("angle", [7.0, -6.3, 400, 1e18])
def test_an_angle_beyond_one_turn_is_a_range_error_naming_the_field(angle: float) -> None:
    """A pose's angle beyond ±2π is bad input wherever it arrives (socket and HTTP: the HTTP
    console answered 409, from the daemon's refusal, until 2026-11-27; the CLI exits 2)."""
    assert finite({"angle_rad": 6.28}, "angle_rad") == 6.28
    assert finite({"x_m": angle}, "x_m") == angle  # only the angle is bounded here
    with pytest.raises(FieldRangeError) as err:
        finite({"angle_rad": angle}, "angle_rad")
    assert str(err.value).startswith(f"angle_rad must lie within ±2π (one turn), got {angle:.6g}")


def test_integer_bounds_and_default() -> None:
    assert integer({}, "steps", 40, 2, 10_000) == 40
    assert integer({"steps": 2}, "steps", 40, 2, 10_000) == 2
    assert integer({"steps": 10_000}, "steps", 40, 2, 10_000) == 10_000
    assert integer({"part": 7}, "part", 1, 1) == 7


@pytest.mark.parametrize("value", [1, 10_001, 2.0, True, "3", None])
def test_integer_refuses(value: object) -> None:
    with pytest.raises(RequestFieldError, match=r"^steps must be an integer in \[2, 10000\], got "):
        integer({"steps": value}, "steps", 40, 2, 10_000)


def test_integer_without_upper_bound_says_so() -> None:
    with pytest.raises(RequestFieldError, match=r"^part must be an integer >= 1, got 0$"):
        integer({"part": 0}, "part", 1, 1)


def test_brief_cuts_long_and_unprintable_values() -> None:
    assert brief("a" * 100) == "'" + "a" * 36 + "..."
    assert brief(10**5000) == "<int too large to print>"
    assert brief(3) == "3"
