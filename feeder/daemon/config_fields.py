"""The typed readers of the configuration file's values (:mod:`feeder.daemon.config_file`).

Each reader takes a TOML table and a key and returns the key's value, or raises
:class:`~feeder.errors.InputError` naming the file (``where``) and the key (with its
section's prefix): a value of the wrong type, a number outside :data:`RANGES` (refused,
not clipped), an unknown key (with the nearest known one).
"""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import Any

from feeder.errors import InputError
from feeder.plant.stack import STACK_RANGES

RANGES: dict[str, tuple[float, float]] = {
    "rate_hz": (1.0, 1000.0),
    "tolerance_m": (1e-9, 1e-3),
    "settle_s": (0.0, 10.0),
    "average_samples": (1, 1000),
    "max_burst_steps": (1, 100_000),
    "stall_fraction": (0.0, 1.0),
    "stall_bursts": (1, 1000),
    "max_reversals": (1, 1000),
    "max_bursts": (1, 100_000),
    "burst_grace_s": (0.0, 60.0),
    "sensor_noise_m": (0.0, 1e-3),
    "step_scatter_fraction": (0.0, 1.0),
    "forgetting": (0.5, 1.0),
    "position_save_s": (0.0, 3600.0),
    "hold_timeout_s": (0.0, 60.0),
    "idle_ground_s": (0.0, 3600.0),
    "timeout_s": (1e-3, 60.0),
    "axis": (1, 7),
    "baudrate": (300, 4_000_000),
    "node_id": (1, 127),
    "host_id": (1, 127),
    "heartbeat_s": (0.01, 10.0),
    "min_position_m": (-1.0, 1.0),
    "max_position_m": (-1.0, 1.0),
    "moves_per_s": (0.01, 1000.0),
    "move_burst": (1, 1000),
    "min_y_m": (-1.0, 1.0),
    "max_y_m": (-1.0, 1.0),
    "tolerance_rad": (1e-6, 0.5),
    "lever_arm_m": (1e-4, 1.0),
    "pixel_size_m": (1e-9, 1e-3),
    "width_px": (16, 8192),
    "height_px": (16, 8192),
    "fps": (0.1, 1000.0),
    **STACK_RANGES,
}
"""Accepted ranges of numeric keys (a value outside is refused, not clipped)."""


def subtable(doc: dict[str, Any], name: str, where: str, section: str = "") -> dict[str, Any]:
    """``doc[name]``, a table (empty when absent); errors name ``[section + name]``."""
    value = doc.get(name, {})
    if not isinstance(value, dict):
        raise InputError(where, f"[{section}{name}] must be a table")
    return value


def check_keys(table: dict[str, Any], known: frozenset[str] | set[str], where: str, prefix: str) -> None:
    """Refuse an unknown key, naming the nearest known one."""
    for key in table:
        if key not in known:
            near = difflib.get_close_matches(str(key), sorted(known), n=1)
            hint = f"; did you mean {prefix}{near[0]}?" if near else f"; known: {', '.join(sorted(known))}"
            raise InputError(where, f"unknown key {prefix}{key}{hint}")


def number(
    table: dict[str, Any], key: str, where: str, default: float, positive: bool = False, section: str = ""
) -> float:
    """``table[key]`` as a finite float within :data:`RANGES`; errors name ``section + key``."""
    name = section + key
    value = table.get(key, default)
    try:
        number = math.nan if isinstance(value, bool) else float(value)
    except (TypeError, ValueError, OverflowError):
        number = math.nan
    if not math.isfinite(number):
        shown = value if isinstance(value, (str, float, bool)) else type(value).__name__
        raise InputError(where, f"{name} must be a finite number, got {shown!r}")
    if positive and number <= 0:
        raise InputError(where, f"{name} must be positive, got {number!r}")
    low, high = RANGES.get(key, (-math.inf, math.inf))
    if not low <= number <= high:
        raise InputError(where, f"{name} = {number:g} is outside [{low:g}, {high:g}]")
    return number


def integer(table: dict[str, Any], key: str, where: str, default: int, section: str = "") -> int:
    """``table[key]`` as an integer within :data:`RANGES`; errors name ``section + key``."""
    name = section + key
    value = table.get(key, default)
    if not isinstance(value, int) or isinstance(value, bool):
        raise InputError(where, f"{name} must be an integer, got {type(value).__name__}")
    low, high = RANGES.get(key, (1, math.inf))
    if not low <= value <= high:
        shown = value if abs(value) < 10**12 else "a huge integer"
        raise InputError(where, f"{name} = {shown} is outside [{low:g}, {high:g}]")
    return value


def string(
    table: dict[str, Any], key: str, where: str, default: str | None, section: str = "", empty: bool = False
) -> str | None:
    """``table[key]`` as a string (``default`` when absent), not empty unless ``empty``; errors
    name ``section + key``."""
    value = table.get(key, default)
    if value is not None and not isinstance(value, str):
        raise InputError(where, f"{section}{key} must be a string, got {value!r}")
    if value is not None and not empty and not value.strip():
        raise InputError(where, f"{section}{key} is empty: give a value, or leave the key out")
    return value


def expanded_path(value: str | None, folder: Path | None = None) -> Path | None:
    """``value`` with ``~`` expanded; a relative path joined to ``folder`` when given."""
    if value is None:
        return None
    path = Path(value).expanduser()
    return path if folder is None else folder / path


def flag(table: dict[str, Any], key: str, where: str, section: str) -> bool:
    """A true/false key, default false."""
    value = table.get(key, False)
    if not isinstance(value, bool):
        raise InputError(where, f"{section}{key} must be true or false, got {value!r}")
    return value
