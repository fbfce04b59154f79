"""Shared output helpers for the sub-commands (JSON objects, SI units; a closed stdout)."""

from __future__ import annotations

import io
import json
import math
import os
import sys
from typing import Any, NoReturn

CLOSED_STDOUT_EXIT = 141
"""Exit status when the reader of stdout went away (``feeder contact --table --json | head``):
128 + SIGPIPE, what a shell reports for ``cat`` or ``grep`` killed by the same closed pipe. Not 0:
the output was cut short, and ``set -o pipefail`` scripts may want to know; not 1–3, which say
the daemon refused, the input was bad or the daemon is unreachable."""


def exit_on_closed_stdout() -> NoReturn:
    """Leave quietly after a BrokenPipeError on stdout: no traceback, no "Exception ignored" when
    Python flushes stdout at exit (stdout now points at the null device), exit status 141."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, sys.stdout.fileno())
        finally:
            os.close(devnull)
    except (OSError, ValueError, io.UnsupportedOperation):  # stdout is not a file (captured, closed)
        pass
    raise SystemExit(CLOSED_STDOUT_EXIT)


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
