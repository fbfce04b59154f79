"""Shared output helpers for the sub-commands (JSON objects, SI units)."""

from __future__ import annotations

import json
import math
import sys
from typing import Any


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    np = sys.modules.get("numpy")  # no numpy value exists before numpy is imported
    if np is not None and isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if np is not None and isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def print_json(obj: dict[str, Any]) -> None:
    """Print one JSON object (numpy values converted, NaN/inf as null)."""
    print(json.dumps(_plain(obj), indent=2, sort_keys=False))
