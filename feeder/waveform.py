"""Stepping waveforms: a sawtooth with a slow rise and a fast flyback (paper §V.B).

One period of the *shape* s(φ), φ ∈ [0, 1), runs from 0 to 1 and back:

- ``forward``: s rises linearly from 0 to 1 over the rise, then flies back to 0
  over the flyback.  The plate ramps slowly towards +x and flies back fast, so
  the part advances in +x.  ``backward`` is the mirror image, 1 − s.
- flyback shapes: ``linear`` (1 − τ/t_f), ``half-cosine`` ((1 + cos πτ/t_f)/2,
  zero slope at both ends of the flyback), ``current-limited`` (the command
  drops at once; the amplifier's current limit into the stack capacitance sets
  the real flyback, t_f ≈ C·ΔV/I_max, see :mod:`feeder.plant.amplifier`).

The output voltage is ``offset_v + amplitude_vpp · s(φ)``.  Tables for a DAC
hold s as unsigned codes (0 → 0, full scale → 1), so a firmware scales them by
the amplitude and adds the offset.

TOML file::

    [waveform]
    shape = "sawtooth"
    frequency_hz = 100.0
    amplitude_vpp = 200.0
    offset_v = 0.0
    flyback_shape = "current-limited"   # or "linear", "half-cosine"
    flyback_s = 1.0e-4                  # for linear / half-cosine
    direction = "forward"               # or "backward"

A *design file* is a waveform file with more tables beside ``[waveform]``
(``feeder plan --out``, ``feeder waveform design --out``): ``[amplifier]`` (the
limits it was designed within, see :func:`feeder.plant.amplifier.load_amplifier`),
``[stack]``, ``[prediction]`` (part, support, τ, w, predicted step and band) and
``[design]`` / ``[margins]``.  :func:`load_waveform` reads only ``[waveform]``,
so every reader of waveform files plays a design file;
:func:`read_waveform_tables` returns the other tables.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from feeder.errors import InputError
from feeder.files import read_toml, toml_number, toml_tables, write_text

SHAPES = ("sawtooth",)
FLYBACK_SHAPES = ("linear", "half-cosine", "current-limited")
DIRECTIONS = ("forward", "backward")
ANC300_TABLE_POINTS = 256
DEFAULT_DAC_POINTS = 1024
DEFAULT_DAC_BITS = 16


@dataclass(frozen=True)
class Waveform:
    """A stepping sawtooth (SI units; volts at the amplifier output).

    flyback_s: flyback duration for ``linear`` and ``half-cosine``; ignored
    (may be ``None``) for ``current-limited``, where the amplifier sets it.
    """

    frequency_hz: float = 100.0
    amplitude_vpp: float = 200.0
    offset_v: float = 0.0
    flyback_shape: str = "current-limited"
    flyback_s: float | None = None
    direction: str = "forward"
    shape: str = "sawtooth"

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise InputError("shape", f"expected one of {', '.join(SHAPES)}, got {self.shape!r}")
        if self.flyback_shape not in FLYBACK_SHAPES:
            raise InputError(
                "flyback_shape",
                f"expected one of {', '.join(FLYBACK_SHAPES)}, got {self.flyback_shape!r}",
            )
        if self.direction not in DIRECTIONS:
            raise InputError("direction", f"expected one of {', '.join(DIRECTIONS)}, got {self.direction!r}")
        if not (math.isfinite(self.frequency_hz) and self.frequency_hz > 0):
            raise InputError("frequency_hz", f"must be a positive number, got {self.frequency_hz!r}")
        if not (math.isfinite(self.amplitude_vpp) and self.amplitude_vpp > 0):
            raise InputError("amplitude_vpp", f"must be a positive number, got {self.amplitude_vpp!r}")
        if not math.isfinite(self.offset_v):
            raise InputError("offset_v", f"must be a finite number, got {self.offset_v!r}")
        if self.flyback_shape != "current-limited":
            if self.flyback_s is None:
                raise InputError("flyback_s", f"required for flyback_shape {self.flyback_shape!r}")
            if not (math.isfinite(self.flyback_s) and self.flyback_s > 0):
                raise InputError("flyback_s", f"must be a positive number, got {self.flyback_s!r}")
            if self.flyback_s >= self.period_s:
                raise InputError(
                    "flyback_s",
                    f"{self.flyback_s:g} s is not shorter than the period {self.period_s:g} s",
                )
        elif self.flyback_s is not None and not (math.isfinite(self.flyback_s) and self.flyback_s > 0):
            raise InputError("flyback_s", f"must be a positive number, got {self.flyback_s!r}")

    @property
    def period_s(self) -> float:
        return 1.0 / self.frequency_hz

    @property
    def sign(self) -> float:
        """+1 for forward (part moves towards +x), −1 for backward."""
        return 1.0 if self.direction == "forward" else -1.0

    @property
    def max_voltage_v(self) -> float:
        return self.offset_v + self.amplitude_vpp

    @property
    def command_flyback_s(self) -> float:
        """Flyback of the command itself: 0 for ``current-limited`` (an instant drop)."""
        if self.flyback_shape == "current-limited" or self.flyback_s is None:
            return 0.0
        return self.flyback_s

    def shape_at(self, phase: np.ndarray | float) -> np.ndarray:
        """Shape s ∈ [0, 1] at phase φ (periods; wrapped to [0, 1)), vectorised."""
        phi = np.mod(np.asarray(phase, dtype=float), 1.0)
        fly = self.command_flyback_s * self.frequency_hz
        rise = 1.0 - fly
        s = np.minimum(phi / rise, 1.0)
        if fly > 0:
            tau = np.clip((phi - rise) / fly, 0.0, 1.0)
            down = 1.0 - tau if self.flyback_shape == "linear" else 0.5 * (1.0 + np.cos(np.pi * tau))
            s = np.where(phi > rise, down, s)
        return s if self.direction == "forward" else 1.0 - s

    def voltage_at_phase(self, phase: np.ndarray | float) -> np.ndarray:
        """Command voltage (V) at phase φ (periods), vectorised; φ = 0 starts a rise."""
        return self.offset_v + self.amplitude_vpp * self.shape_at(phase)

    def voltage_at(self, time_s: np.ndarray | float) -> np.ndarray:
        """Command voltage (V) at the given times, vectorised; t = 0 starts a rise."""
        return self.voltage_at_phase(np.asarray(time_s, dtype=float) * self.frequency_hz)

    def table(self, points: int = DEFAULT_DAC_POINTS) -> np.ndarray:
        """``points`` samples of the shape s at phases k/points (float, 0–1)."""
        if points < 4:
            raise InputError("points", f"a table needs at least 4 points, got {points}")
        return self.shape_at(np.arange(points) / points)

    def dac_table(self, points: int = DEFAULT_DAC_POINTS, bits: int = DEFAULT_DAC_BITS) -> np.ndarray:
        """The shape as unsigned DAC codes 0 … 2**bits − 1 (uint16 for ≤ 16 bits)."""
        if not 1 <= bits <= 16:
            raise InputError("bits", f"must be 1–16, got {bits}")
        full = (1 << bits) - 1
        return np.rint(self.table(points) * full).astype(np.uint16)

    def anc300_tables(self) -> tuple[list[int], list[int]]:
        """The ANC300's 256-point ``setpu``/``setpd`` tables, values 0–255.

        ``up`` is this design stepping forward, ``down`` the same design stepping
        backward (the direction field chooses which one a step burst uses).  The
        ``current-limited`` sawtooth is the exact ramp 0, 1, …, 255 (the drop falls
        in the last 1/256 of the period and the current limit sets the flyback):
        8-bit rounding of a ramp over 256 points would repeat a value, a slope
        change that can shake a part loose at low amplitude.
        """
        if self.flyback_shape == "current-limited":
            ramp = list(range(ANC300_TABLE_POINTS))
            return ramp, [255 - v for v in ramp]
        fwd = Waveform(
            frequency_hz=self.frequency_hz,
            amplitude_vpp=self.amplitude_vpp,
            offset_v=self.offset_v,
            flyback_shape=self.flyback_shape,
            flyback_s=self.flyback_s,
            direction="forward",
        )
        up = np.rint(fwd.table(ANC300_TABLE_POINTS) * 255).astype(int)
        return up.tolist(), (255 - up).tolist()

    def to_toml(self) -> str:
        lines = [
            "[waveform]",
            f'shape = "{self.shape}"',
            f"frequency_hz = {self.frequency_hz!r}",
            f"amplitude_vpp = {self.amplitude_vpp!r}",
            f"offset_v = {self.offset_v!r}",
            f'flyback_shape = "{self.flyback_shape}"',
        ]
        if self.flyback_s is not None:
            lines.append(f"flyback_s = {self.flyback_s!r}")
        lines += [f'direction = "{self.direction}"', ""]
        return "\n".join(lines)

    def write_toml(self, path: Path) -> None:
        """Write atomically (temporary file, then rename)."""
        write_text(path, self.to_toml())


def write_waveform_file(
    path: Path | str, waveform: Waveform, tables: Mapping[str, Mapping[str, Any]], comment: str = ""
) -> None:
    """Write a design file atomically: ``[waveform]`` then ``tables`` (flat; None values skipped).

    ``comment`` lines go first as TOML comments.
    """
    if "waveform" in tables:
        raise ValueError("tables: [waveform] is written from the Waveform itself")
    head = "".join(f"# {line}\n" for line in comment.splitlines())
    write_text(Path(path), head + waveform.to_toml() + "\n" + toml_tables(tables))


def read_waveform_tables(path: Path | str) -> dict[str, dict[str, Any]]:
    """The tables of a waveform file other than ``[waveform]`` (empty for a plain waveform file)."""
    data = read_toml(Path(path))
    return {k: v for k, v in data.items() if k != "waveform" and isinstance(v, dict)}


_NUMBER_KEYS = ("frequency_hz", "amplitude_vpp", "offset_v", "flyback_s")
_TEXT_KEYS = ("shape", "flyback_shape", "direction")


def load_waveform(path: Path | str) -> Waveform:
    """Read a waveform TOML file; every problem is an :class:`InputError` naming file and field.

    Checks the waveform on its own (shape, positive frequency, flyback shorter
    than the period); check it against an amplifier with
    :meth:`feeder.plant.amplifier.AmplifierLimits.check`.
    """
    path = Path(path)
    data = read_toml(path)
    table = data.get("waveform")
    if not isinstance(table, dict):
        raise InputError(str(path), "missing [waveform] table")
    values: dict[str, object] = {}
    for key, value in table.items():
        field = f"{path}: [waveform].{key}"
        if key in _NUMBER_KEYS:
            values[key] = toml_number(field, value)
        elif key in _TEXT_KEYS:
            if not isinstance(value, str):
                raise InputError(field, f"must be a string, got {value!r}")
            values[key] = value
        else:
            raise InputError(field, "unknown field")
    for key in ("frequency_hz", "amplitude_vpp"):
        if key not in values:
            raise InputError(f"{path}: [waveform].{key}", "missing")
    try:
        return Waveform(**values)  # type: ignore[arg-type]
    except InputError as err:
        raise InputError(f"{path}: [waveform].{err.field}", err.message) from None
