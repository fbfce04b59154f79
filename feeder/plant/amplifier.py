"""The piezo amplifier's nonlinear limits: rails, slew rate, current into the stack.

The output stage follows the command voltage within its rails, but its output
can change no faster than min(slew rate, I_max/C): a capacitive stack draws
I = C·dV/dt.  A sawtooth command that drops at once therefore flies back along
a ramp of slope I_max/C: the *current-limited* flyback, t_f ≈ C·ΔV/I_max.

Defaults (document of record: docs/plant.md): 0–200 V rails (the paper drives
200 Vpp), 0.55 A peak current and 2 V/µs slew, which is a mid-range
commercial piezo driver (0.1–1 A class); 1 Hz–2 kHz stepping frequency.

:data:`AMPLIFIER_MODELS` names the ratings a planner plans within: ``anc300``
(attocube ANC300 with ANM150 stepping modules: 0–150 V, 1 Hz–10 kHz in whole hertz,
256-point 8-bit waveform tables; its current and slew limits are not published in the
console, so the mid-range defaults stand until ``[amplifier.limits]`` says
better) and ``firmware_sim`` (the feeder's own amplifier, the paper's 200 Vpp).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from feeder.errors import InputError, shown
from feeder.files import read_toml, toml_number
from feeder.waveform import Waveform


@dataclass(frozen=True)
class AmplifierLimits:
    """Rails (V), slew rate (V/s), peak current (A) and allowed stepping frequencies (Hz)."""

    v_min_v: float = 0.0
    v_max_v: float = 200.0
    slew_rate_v_per_s: float = 2.0e6
    current_limit_a: float = 0.55
    min_frequency_hz: float = 1.0
    max_frequency_hz: float = 2000.0
    frequency_step_hz: float = 0.0
    """The stepping frequency is set in steps of this (the ANC300: whole hertz); 0: any."""

    def __post_init__(self) -> None:
        for name in ("slew_rate_v_per_s", "current_limit_a", "min_frequency_hz", "max_frequency_hz"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(name, f"must be a positive number, got {value!r}")
        if not (
            math.isfinite(self.frequency_step_hz) and 0 <= self.frequency_step_hz <= self.max_frequency_hz
        ):
            raise InputError(
                "frequency_step_hz", f"must be 0 or a positive step, got {self.frequency_step_hz!r}"
            )
        if not (math.isfinite(self.v_min_v) and math.isfinite(self.v_max_v)
                and self.v_min_v < self.v_max_v):  # fmt: skip
            raise InputError("v_max_v", "rails must be finite with v_min_v < v_max_v")
        if self.min_frequency_hz > self.max_frequency_hz:
            raise InputError("max_frequency_hz", "must not be below min_frequency_hz")

    def settable_hz(self, frequency_hz: float) -> float:
        """The nearest frequency the amplifier can be set to (Hz; its steps, within its range)."""
        step = self.frequency_step_hz
        if step <= 0:
            return frequency_hz
        lowest, highest = (
            math.ceil(self.min_frequency_hz / step) * step,
            math.floor(self.max_frequency_hz / step) * step,
        )
        return min(max(round(frequency_hz / step) * step, lowest), highest)

    @property
    def max_amplitude_vpp(self) -> float:
        return self.v_max_v - self.v_min_v

    def max_slope_v_per_s(self, capacitance_f: float) -> float:
        """Fastest output change into a stack of capacitance C: min(slew, I_max/C)."""
        return min(self.slew_rate_v_per_s, self.current_limit_a / capacitance_f)

    def check(self, waveform: Waveform, field_prefix: str = "") -> None:
        """Raise :class:`InputError` if the waveform leaves the rails or the frequency range."""
        low, high = waveform.offset_v, waveform.offset_v + waveform.amplitude_vpp
        if high > self.v_max_v * (1 + 1e-12) or low < self.v_min_v - 1e-12 * abs(self.v_max_v):
            field = "amplitude_vpp" if low >= self.v_min_v else "offset_v"
            raise InputError(
                f"{field_prefix}{field}",
                f"output {low:g}…{high:g} V leaves the amplifier's rails {self.v_min_v:g}…{self.v_max_v:g} V",
            )
        if not self.min_frequency_hz <= waveform.frequency_hz <= self.max_frequency_hz:
            raise InputError(
                f"{field_prefix}frequency_hz",
                f"{waveform.frequency_hz:g} Hz is outside the amplifier's "
                f"{self.min_frequency_hz:g}–{self.max_frequency_hz:g} Hz",
            )

    def current_limited_flyback(
        self, amplitude_v: np.ndarray | float, frequency_hz: np.ndarray | float, capacitance_f: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Flyback of a sawtooth whose command drops at once: (t_f in s, swing fraction).

        The output falls at r = min(slew, I/C) while the command already rises at
        ΔV·f, so they meet after t_f = ΔV/(r + ΔV·f); the output then swings over
        the fraction 1 − t_f·f of ΔV (rise and flyback alike).
        """
        dv = np.asarray(amplitude_v, dtype=float)
        f = np.asarray(frequency_hz, dtype=float)
        t_f = dv / (self.max_slope_v_per_s(capacitance_f) + dv * f)
        return t_f, 1.0 - t_f * f


class OutputStage:
    """Streaming amplifier output: rails, then the slope limit, state kept across calls.

    Events, not a per-sample loop: spans where the output tracks the command are
    copied in bulk, each slope-limited run is a ramp found in one vectorised step.
    """

    def __init__(self, limits: AmplifierLimits, capacitance_f: float, sample_rate_hz: float,
                 initial_v: float = 0.0) -> None:  # fmt: skip
        self.limits = limits
        self.max_step_v = limits.max_slope_v_per_s(capacitance_f) / sample_rate_hz
        self.voltage_v = float(np.clip(initial_v, limits.v_min_v, limits.v_max_v))

    def advance(self, command_v: np.ndarray) -> np.ndarray:
        """Output voltage for each command sample."""
        u = np.minimum(np.maximum(np.asarray(command_v, dtype=float), self.limits.v_min_v),
                       self.limits.v_max_v)  # fmt: skip
        n = u.size
        out = np.empty(n)
        d = self.max_step_v
        fast = np.flatnonzero(np.abs(u[1:] - u[:-1]) > d) + 1  # samples a tracking output cannot follow
        y = self.voltage_v
        i = 0
        while i < n:
            if abs(u[i] - y) <= d:  # track the command up to the next fast change
                k = int(np.searchsorted(fast, i, side="right"))
                j = int(fast[k]) if k < fast.size else n
                out[i:j] = u[i:j]
                y = float(u[j - 1])
                i = j
                continue
            sign = math.copysign(1.0, u[i] - y)
            window = 64
            while True:  # slope-limited ramp until it reaches the command
                stop = min(n, i + window)
                line = y + sign * d * np.arange(1, stop - i + 1)
                reach = np.flatnonzero(sign * (u[i:stop] - line) <= 0)
                m = i + int(reach[0]) if reach.size else stop
                if m == i:  # |u − y| a rounding error above d: the first ramp sample is u itself
                    out[i] = u[i]
                    y = float(u[i])
                    i += 1
                    break
                out[i:m] = line[: m - i]
                y = float(out[m - 1]) if m > i else y
                i = m
                if reach.size or i == n:
                    break
                window *= 2
        self.voltage_v = y
        return out


AMPLIFIER_MODELS: dict[str, AmplifierLimits] = {
    "anc300": AmplifierLimits(v_max_v=150.0, max_frequency_hz=10_000.0, frequency_step_hz=1.0),
    "firmware_sim": AmplifierLimits(),
}
"""Named amplifier ratings (``[amplifier] model`` in the daemon's configuration)."""


def amplifier_model(name: str, field: str = "model") -> AmplifierLimits:
    """The rating of a named amplifier model (or an alias, :data:`AMPLIFIER_ALIASES`);
    :class:`InputError` names the known ones."""
    try:
        return AMPLIFIER_MODELS[AMPLIFIER_ALIASES.get(name, name)]
    except KeyError:
        raise InputError(
            field, f"unknown amplifier model {name!r}; known: {', '.join(AMPLIFIER_MODELS)}"
        ) from None


def within_rating(limits: AmplifierLimits, rating: AmplifierLimits, model: str) -> None:
    """Refuse ``limits`` that ask more of the amplifier than its model's ``rating`` gives: rails
    and frequencies beyond it, a frequency step that is not a multiple of its own.  The current
    limit and slew rate are the unit's own figures (a model's are mid-range defaults)."""
    checks = (
        ("v_max_v", limits.v_max_v > rating.v_max_v, rating.v_max_v, "V"),
        ("v_min_v", limits.v_min_v < rating.v_min_v, rating.v_min_v, "V"),
        (
            "max_frequency_hz",
            limits.max_frequency_hz > rating.max_frequency_hz,
            rating.max_frequency_hz,
            "Hz",
        ),
        (
            "min_frequency_hz",
            limits.min_frequency_hz < rating.min_frequency_hz,
            rating.min_frequency_hz,
            "Hz",
        ),
    )
    for name, beyond, value, unit in checks:
        if beyond:
            raise InputError(
                name, f"{getattr(limits, name):g} {unit} is beyond the {model}'s rating ({value:g} {unit})"
            )
    step, rated = limits.frequency_step_hz, rating.frequency_step_hz
    if rated > 0 and not (step >= rated and math.isclose(step / rated, round(step / rated))):
        raise InputError(
            "frequency_step_hz",
            f"{step:g} Hz: the {model} sets its frequency in steps of {rated:g} Hz (or a multiple of it)",
        )


AMPLIFIER_ALIASES: dict[str, str] = {"paper": "firmware_sim"}
"""Other names for :data:`AMPLIFIER_MODELS` (the paper's 200 Vpp amplifier is the firmware_sim rating)."""
LIMIT_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(AmplifierLimits))


def limits_from_table(table: Mapping[str, Any], where: str) -> AmplifierLimits:
    """AmplifierLimits from a TOML table of its fields (``model`` optional: the base for missing ones).

    ``where`` prefixes every error's field, e.g. ``"amp.toml: [amplifier]."``.
    """
    model = table.get("model")
    if model is not None and not isinstance(model, str):
        raise InputError(f"{where}model", f"must be a string, got {model!r}")
    name = AMPLIFIER_ALIASES.get(model, model) if model else None
    missing = [key for key in LIMIT_FIELDS if key not in table]
    if name and name not in AMPLIFIER_MODELS and missing:
        # a design file names its amplifier by model or by the file it came from and lists
        # every limit; an unknown base (a typo) must not silently fill the rest with defaults
        known = ", ".join([*AMPLIFIER_MODELS, *AMPLIFIER_ALIASES])
        raise InputError(f"{where}model", f"{shown(str(model))} is not a known amplifier ({known}) to take "
                         f"{', '.join(missing)} from; name one or give every limit")  # fmt: skip
    base = AMPLIFIER_MODELS.get(name, AmplifierLimits()) if name else AmplifierLimits()
    values: dict[str, float] = {}
    for key, value in table.items():
        if key == "model":
            continue
        if key not in LIMIT_FIELDS:
            raise InputError(f"{where}{key}", f"unknown field; known: model, {', '.join(LIMIT_FIELDS)}")
        values[key] = toml_number(f"{where}{key}", value)
    try:
        return AmplifierLimits(**{**asdict(base), **values})
    except InputError as err:
        raise InputError(f"{where}{err.field}", err.message) from None


def load_amplifier(path: Path | str) -> AmplifierLimits:
    """Amplifier limits from a TOML file: its ``[amplifier]`` table, else its top-level keys.

    A design file (``[waveform]`` + ``[amplifier]``) therefore names the
    amplifier it was designed for.
    """
    path = Path(path)
    data = read_toml(path)
    if isinstance(data.get("amplifier"), dict):
        return limits_from_table(data["amplifier"], f"{path}: [amplifier].")
    if any(isinstance(v, dict) for v in data.values()):
        raise InputError(str(path), "no [amplifier] table and not a flat table of amplifier limits")
    return limits_from_table(data, f"{path}: ")


def resolve_amplifier(spec: str, field: str = "--amplifier") -> tuple[str, AmplifierLimits]:
    """(model name, limits) for a model name (:data:`AMPLIFIER_MODELS`, ``paper``) or a TOML file."""
    name = AMPLIFIER_ALIASES.get(spec, spec)
    if name in AMPLIFIER_MODELS:
        return name, amplifier_model(name, field)
    path = Path(spec)
    try:
        exists = path.exists()
    except OSError:  # e.g. a name too long
        exists = False
    if path.suffix.lower() != ".toml" and not exists:
        known = ", ".join([*AMPLIFIER_MODELS, *AMPLIFIER_ALIASES])
        raise InputError(field, f"{shown(spec)} is neither a known amplifier ({known}) nor a TOML file")
    return str(path), load_amplifier(path)


def amplifier_table(model: str, limits: AmplifierLimits) -> dict[str, Any]:
    """The ``[amplifier]`` table of a design file: model name and every limit."""
    return {"model": model, **asdict(limits)}
