"""Reading height maps: AFM instrument files and plain ``.npy`` / text arrays (paper §IV.C).

Instrument files (Bruker/DI ``.di``/``.spm``, Asylum ``.ibw``, Nanosurf ``.nid``, Park
``.tiff``, WSxM ``.stp``, Gwyddion ``.gwy`` and the other formats of the
`SurfaceTopography <https://github.com/ContactEngineering/SurfaceTopography>`_ package)
are read through that package (the ``afm`` extra, imported only when needed). The file
says its own units (nm, µm or m, different per file); heights and sizes are converted to
metres here.

Channel choice: a file may hold several channels (height trace/retrace, phase, amplitude,
error signals). Unless ``channel`` is given (index or exact name), the reader's default
channel is used if it carries heights (a length unit), otherwise the first channel that
does. Channels without a length unit (phase, amplitude error, ...) are refused.

Plain height maps: ``.npy`` (read by numpy, no pickles) and ``.txt``/``.csv``/``.dat``
(whitespace or comma separated matrix, ``#`` comments) carry no scale, so the caller
gives ``pixel_size_m`` and the ``height_unit`` of the stored numbers (both required: a
map of nanometres read as metres gives σ ≈ 1 m and a summit radius of 1e-17 m).

Every problem is an :class:`~feeder.errors.InputError` naming the file.
"""

from __future__ import annotations

import math
import struct
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from feeder.errors import InputError, check_memory_budget

PLAIN_SUFFIXES = (".npy", ".txt", ".csv", ".dat")
NPY_MAGIC = b"\x93NUMPY"
_WORKING_COPIES = 8  # a scan file's bytes × this: the float64 maps and temporaries of the statistics

LENGTH_UNITS_M = {
    "m": 1.0,
    "mm": 1e-3,
    "um": 1e-6,
    "µm": 1e-6,
    "nm": 1e-9,
    "A": 1e-10,
    "Å": 1e-10,
    "pm": 1e-12,
}
"""Height units accepted for plain height maps (metres per unit)."""


@dataclass(frozen=True)
class HeightMap:
    """A uniformly sampled height map in SI units.

    heights_m: 2-D array (axis 0 × axis 1), metres; pixel_size_m: grid spacing along
    axis 0 and axis 1, metres; source: file name; channel: channel read ("" for plain maps).
    """

    heights_m: np.ndarray
    pixel_size_m: tuple[float, float]
    source: str
    channel: str = ""

    @property
    def scan_size_m(self) -> tuple[float, float]:
        """Physical size along axis 0 and axis 1 (pixels × spacing), metres."""
        n0, n1 = self.heights_m.shape
        return (n0 * self.pixel_size_m[0], n1 * self.pixel_size_m[1])


def read_height_map(
    path: Path,
    channel: str | None = None,
    pixel_size_m: float | None = None,
    height_unit: str | None = None,
) -> HeightMap:
    """Read a height map from an AFM instrument file or a plain array file.

    ``channel`` (instrument files): index or exact channel name. ``pixel_size_m`` and
    ``height_unit`` (plain files only, both required there): sampling interval in metres
    and the unit of the stored heights (a key of :data:`LENGTH_UNITS_M`).
    """
    if not path.is_file():
        raise InputError(str(path), "no such file")
    check_memory_budget(str(path), path.stat().st_size * _WORKING_COPIES)
    if path.suffix.lower() in PLAIN_SUFFIXES:
        heights = _read_plain(path)
        if pixel_size_m is None:
            message = f"{path.name} is a plain height map without scale; give its pixel size in metres"
            raise InputError("--pixel-size", message)
        if not (math.isfinite(pixel_size_m) and pixel_size_m > 0):
            raise InputError("--pixel-size", f"must be a positive number of metres, got {pixel_size_m!r}")
        known = ", ".join(LENGTH_UNITS_M)
        if height_unit is None:
            message = f"{path.name} is a plain height map without units; give its heights' unit ({known})"
            raise InputError("--height-unit", message)
        if height_unit not in LENGTH_UNITS_M:
            raise InputError("--height-unit", f"expected one of {known}, got {height_unit!r}")
        return _checked(heights * LENGTH_UNITS_M[height_unit], (pixel_size_m, pixel_size_m), path, "")
    return _read_instrument(path, channel)


def _read_plain(path: Path) -> np.ndarray:
    try:
        if path.suffix.lower() == ".npy":
            with path.open("rb") as stream:
                if stream.read(6) != NPY_MAGIC:
                    raise ValueError("does not start with the NumPy magic bytes \\x93NUMPY")
            data = np.load(path, allow_pickle=False)
        else:
            delimiter = "," if path.suffix.lower() == ".csv" else None
            data = np.loadtxt(path, delimiter=delimiter, comments="#", ndmin=2)
    except (ValueError, OSError, EOFError) as err:
        kind = "NumPy .npy" if path.suffix.lower() == ".npy" else "numeric text matrix"
        raise InputError(str(path), f"not a valid {kind} file ({_first_line(err)})") from None
    if data.ndim != 2 or not np.issubdtype(data.dtype, np.number) or np.iscomplexobj(data):
        found = f"shape {data.shape} {data.dtype}"
        raise InputError(str(path), f"expected a 2-D array of real heights, got {found}")
    return np.asarray(data, dtype=float)


def _read_instrument(path: Path, channel: str | None) -> HeightMap:
    try:
        with _quiet_import():
            from SurfaceTopography import open_topography
            from SurfaceTopography.Support.UnitConversion import get_unit_conversion_factor
    except ImportError:
        raise InputError(
            str(path), "reading instrument files needs the 'afm' extra (pip install 'feeder[afm]')"
        ) from None
    from SurfaceTopography.Exceptions import ReadFileError, UnknownFileFormat

    # what SurfaceTopography's readers raise on damaged or foreign files: its own errors, and
    # the parsing errors of the formats it decodes (short reads, bad headers, bad numbers)
    read_errors = (ReadFileError, UnknownFileFormat, OSError, EOFError, ValueError, KeyError,
                   IndexError, TypeError, AttributeError, struct.error)  # fmt: skip
    try:
        reader = open_topography(str(path))
    except read_errors as err:
        if type(err).__name__ == "CannotDetectFileFormat":
            raise InputError(str(path), "not a readable topography file (no reader recognises it)") from None
        raise InputError(str(path), f"cannot read: {_first_line(err)}") from None
    info = _choose_channel(reader, path, channel)
    try:
        topography = reader.topography(channel_index=info.index)
        raw = topography.heights()
        sizes = topography.physical_sizes
        unit = topography.unit
        factor = float(get_unit_conversion_factor(unit, "m"))
    except read_errors as err:
        raise InputError(str(path), f"cannot read channel {info.name!r}: {_first_line(err)}") from None
    if np.ma.is_masked(raw):
        raise InputError(str(path), f"channel {info.name!r} has undefined (masked) pixels")
    heights = np.array(raw, dtype=float)
    if heights.ndim != 2 or sizes is None:
        raise InputError(str(path), f"channel {info.name!r} is not a 2-D map with physical sizes")
    pixel = (float(sizes[0]) * factor / heights.shape[0], float(sizes[1]) * factor / heights.shape[1])
    return _checked(heights * factor, pixel, path, str(info.name))


_NOT_HEIGHT_NAMES = ("amplitude", "phase", "potential", "deflection", "current", "friction", "lateral",
                     "error", "frequency", "dissipation", "adhesion", "modulus", "force")  # fmt: skip
"""Channel names of other quantities: Asylum's .ibw files (SurfaceTopography's reader) label every
channel in metres, e.g. AmplitudeTrace beside HeightTrace."""


def _choose_channel(reader: Any, path: Path, channel: str | None) -> Any:
    channels = list(reader.channels)

    def is_height(info: Any) -> bool:
        named = str(info.name).lower()
        return (isinstance(info.unit, str) and info.unit in _length_unit_names() and info.dim == 2
                and not any(word in named for word in _NOT_HEIGHT_NAMES))  # fmt: skip

    if channel is not None:
        chosen = None
        if channel.isdigit() and int(channel) < len(channels):
            chosen = channels[int(channel)]
        else:
            named = [c for c in channels if c.name == channel]
            if len(named) > 1:  # e.g. two "Height" channels (trace and retrace): which one?
                which = ", ".join(str(c.index) for c in named)
                raise InputError("--channel", f"{path.name} has {len(named)} channels named {channel!r} "
                                 f"(indices {which}): give the index")  # fmt: skip
            chosen = named[0] if named else None
        if chosen is None:
            names = ", ".join(f"{c.index}: {c.name}" for c in channels)
            raise InputError("--channel", f"{path.name} has no channel {channel!r} (channels: {names})")
        if not is_height(chosen):
            raise InputError("--channel", f"channel {chosen.name!r} of {path.name} is not a height map")
        return chosen
    default = reader.default_channel
    if is_height(default):
        return default
    for info in channels:
        if is_height(info):
            return info
    raise InputError(str(path), "no channel with heights (length unit) in this file")


@contextmanager
def _quiet_import() -> Iterator[None]:
    """Imports of SurfaceTopography without its "Could not import mpi4py" warning (we run serial)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Could not import mpi4py")
        yield


def _length_unit_names() -> set[str]:
    with _quiet_import():
        from SurfaceTopography.Support.UnitConversion import length_units

    return set(length_units)


def _checked(heights: np.ndarray, pixel: tuple[float, float], path: Path, channel: str) -> HeightMap:
    if min(heights.shape) < 3:
        raise InputError(str(path), f"height map {heights.shape} is too small (need at least 3×3)")
    if not np.all(np.isfinite(heights)):
        raise InputError(str(path), "height map has NaN or infinite values (undefined pixels)")
    if not all(math.isfinite(p) and p > 0 for p in pixel):
        raise InputError(str(path), f"pixel size must be positive, got {pixel}")
    return HeightMap(heights, pixel, str(path), channel)


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return (text[0] if text else type(err).__name__)[:200]
