"""User files: TOML read with one-line errors, text and PNG written atomically.

Every reader raises :class:`feeder.errors.InputError` naming the file; every
writer goes through a temporary file and a rename, so nothing is half-written.
"""

from __future__ import annotations

import json
import math
import os
import stat
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from feeder.errors import InputError

MAX_TEXT_BYTES = 16 * 2**20
"""Largest TOML file read (a device such as /dev/zero or a huge file is refused up front)."""


def read_text(path: Path) -> str:
    """A small UTF-8 text file; a missing, unreadable, non-regular (/dev/zero) or huge file
    (over :data:`MAX_TEXT_BYTES`) is an InputError naming it."""
    try:
        info = Path(path).stat()
        if not stat.S_ISREG(info.st_mode):
            raise InputError(str(path), "not a regular file")
        if info.st_size > MAX_TEXT_BYTES:
            raise InputError(
                str(path), f"larger than {MAX_TEXT_BYTES // 2**20} MiB; not a configuration file"
            )
        return Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(str(path), "no such file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(str(path), f"cannot read: {err}") from None


def read_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML file; a missing, unreadable or malformed file is an InputError naming it."""
    try:
        return tomllib.loads(read_text(path))
    except tomllib.TOMLDecodeError as err:
        raise InputError(str(path), f"not valid TOML: {err}") from None


def toml_number(field: str, value: Any) -> float:
    """A number read from TOML as a float; a bool, a string or an integer beyond float range
    (400 digits) is an InputError naming ``field``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(field, f"must be a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:
        raise InputError(field, f"number out of range ({len(str(abs(value)))} digits)") from None


def _toml_value(key: str, value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"{key}: TOML files here hold finite numbers only, got {value!r}")
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)  # a JSON string is a TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(key, v) for v in value) + "]"
    raise TypeError(f"{key}: cannot write {type(value).__name__} to TOML")


def toml_tables(tables: Mapping[str, Mapping[str, Any]]) -> str:
    """TOML text of flat tables of numbers, strings, booleans and lists of them (None skipped)."""
    blocks = []
    for name, values in tables.items():
        lines = [f"[{name}]"]
        lines += [f"{key} = {_toml_value(key, value)}" for key, value in values.items()
                  if value is not None]  # fmt: skip
        blocks.append("\n".join(lines) + "\n")
    return "\n".join(blocks)


def _temporary(path: Path) -> Path:
    """The temporary beside ``path``; refuses to replace anything but a regular file (a device
    such as /dev/zero, a directory, a socket): the rename would put a file in its place."""
    try:
        info = path.stat()
    except FileNotFoundError:
        return path.with_name(f".{path.name}.{os.getpid()}.tmp")
    except OSError as err:
        raise InputError(str(path), f"cannot write: {err.strerror or err}") from None
    if not stat.S_ISREG(info.st_mode):
        raise InputError(str(path), "cannot write: exists and is not a regular file")
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (temporary file, then rename)."""
    write_bytes(path, text.encode("utf-8"))


def write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file, then rename); an OSError
    (no such directory, a directory in the way, disk full) is an InputError naming the file."""
    tmp = _temporary(path)
    try:
        tmp.write_bytes(data)
        tmp.replace(path)
    except OSError as err:
        raise InputError(str(path), f"cannot write: {err.strerror or err}") from None
    finally:
        tmp.unlink(missing_ok=True)


def save_figure(fig: Any, path: Path, dpi: int = 120) -> None:
    """Save a matplotlib figure atomically in the format its suffix names where matplotlib
    writes it (``.pdf``, ``.svg``, ...), else PNG; and close it."""
    import matplotlib.pyplot as plt

    suffix = path.suffix.lower().lstrip(".")
    kind = suffix if suffix in fig.canvas.get_supported_filetypes() else "png"
    tmp = _temporary(path)
    try:
        fig.savefig(tmp, dpi=dpi, format=kind)
        tmp.replace(path)
    except OSError as err:
        raise InputError(str(path), f"cannot write: {err.strerror or err}") from None
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)
