"""A sweep's spec: the TOML file, its checks and the points it expands to (:mod:`feeder.sweep` runs them).

Spec (TOML)::

    [sweep]
    model = "plant"             # full plant (amplifier, stack, exact stick-slip) or "ideal" (ideal plate)
    periods = 5                 # periods per point (plant: after a lead-in rise; ideal: at least 3,
                                # doubled up to 512 until the step settles)
    amplifier = "firmware_sim"  # a model name (anc300, paper) or a TOML file of amplifier limits
    sample = "grid"             # every combination, or "random": `points` draws with `seed`
    chunk_size = 50             # points per task and per Parquet part file
    # points = 2000
    # seed = 1

    [parameters]                # a list: the values (grid) or the choices (random)
    frequency_hz = {min = 50.0, max = 1000.0, num = 8, log = true}   # a range: num values (grid)
    amplitude_vpp = [100.0, 150.0, 200.0]                            # or uniform/log-uniform draws
    flyback_shape = ["current-limited", "linear"]
    flyback_s = [2e-4]          # for linear / half-cosine (ignored for current-limited)
    part = ["300x300x50", "500x500x50"]
    support = ["flat"]
    surface = ["embedded"]      # or paths of surface TOML files
    tau_pa = [22.18e9]
    kinetic_ratio = [0.8]
    scatter = [0.0, 0.05]       # relative per-stick scatter of a_s (plant model)
    seed = [0, 1, 2]            # scatter seed

Parameters left out take the defaults above.  Sizes are checked before anything
is expanded or run (an :class:`~feeder.errors.InputError` naming the key):
``periods`` is at most :data:`MAX_PERIODS` (as ``feeder simulate --periods``) and
one evaluation (a plant point, or an ideal-model chunk) must fit the 2 GiB memory
budget (:data:`~feeder.errors.MEMORY_BUDGET_BYTES`); the number of points (a grid's
``num`` and the product of its value counts, or a random sample's ``points``) is at
most :data:`MAX_POINTS`.  Every point is one row of the
result, with every input column and ``point`` (its index), ``breakaway_accel_m_s2``,
``step_mean_m`` and ``step_std_m`` (over the steady periods:
:func:`~feeder.plant.steady_state.steady_start`), ``transient_periods`` (the periods before
them), ``steady`` (the step settled: the last two periods agree; null with scatter, whose
steps vary by design), ``speed_m_s``, ``slip_fraction`` and ``error`` (empty, or why the
point could not run, e.g. a flyback longer than the rise).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from feeder.contact.breakaway import DEFAULT_TAU_PA
from feeder.errors import MEMORY_BUDGET_BYTES, InputError
from feeder.files import read_toml
from feeder.parts import Part, Support
from feeder.plant.amplifier import AmplifierLimits, resolve_amplifier
from feeder.plant.ideal_plate import COSINE_PIECES
from feeder.plant.plant import BYTES_PER_SAMPLE, DEFAULT_SAMPLE_RATE_HZ, MAX_PERIODS
from feeder.plant.stack import StackParameters
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO
from feeder.surface.parameters import load_surface
from feeder.waveform import FLYBACK_SHAPES

MODELS = ("plant", "ideal")
DEFAULTS: dict[str, Any] = {
    "frequency_hz": 100.0,
    "amplitude_vpp": 200.0,
    "flyback_shape": "current-limited",
    "flyback_s": 2e-4,
    "part": "500x500x50",
    "support": "flat",
    "surface": "embedded",
    "tau_pa": DEFAULT_TAU_PA,
    "kinetic_ratio": DEFAULT_KINETIC_RATIO,
    "scatter": 0.0,
    "seed": 0,
}
"""The input columns and their values when a spec leaves them out."""
_TEXT = ("flyback_shape", "part", "support", "surface")
_INTEGER = ("seed",)
OUTPUTS = ("breakaway_accel_m_s2", "step_mean_m", "step_std_m", "transient_periods", "steady", "speed_m_s",
           "slip_fraction", "error")  # fmt: skip
_BYTES_PER_POINT = 2048  # a point's dict, its result row and Parquet round trip (measured ~1 KiB)
MAX_POINTS = MEMORY_BUDGET_BYTES // _BYTES_PER_POINT
"""The most points a sweep may have (1 048 576: the memory budget at ~2 KiB a point)."""


@dataclass(frozen=True)
class SweepSettings:
    """How every point is evaluated (the same for all points of a sweep)."""

    model: str = "plant"
    periods: int = 5
    amplifier_model: str = "firmware_sim"
    amplifier: AmplifierLimits = field(default_factory=AmplifierLimits)
    stack: StackParameters = field(default_factory=StackParameters)

    def key(self) -> str:
        """Canonical JSON of the settings (part of every chunk's hash)."""
        return json.dumps({"model": self.model, "periods": self.periods,
                           "amplifier": asdict(self.amplifier), "stack": asdict(self.stack)},
                          sort_keys=True)  # fmt: skip


@dataclass(frozen=True)
class SweepSpec:
    """A parsed spec: settings, the points (one dict of inputs per point) and the chunk size."""

    settings: SweepSettings
    points: list[dict[str, Any]]
    chunk_size: int

    def chunks(self) -> list[list[dict[str, Any]]]:
        n = self.chunk_size
        return [self.points[i : i + n] for i in range(0, len(self.points), n)]


def chunk_key(settings: SweepSettings, rows: list[dict[str, Any]]) -> str:
    """Hash of a chunk's inputs and settings: its part file's name."""
    text = settings.key() + json.dumps(rows, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def _values(name: str, value: Any, where: str, grid: bool) -> list[Any] | dict[str, float]:
    """A parameter's values (grid) or, for random sampling, a range table as-is."""
    if isinstance(value, list):
        if not value:
            raise InputError(where, "an empty list")
        return value
    if isinstance(value, dict):
        if name in _TEXT or name in _INTEGER:
            raise InputError(where, "takes a list of values, not a range")
        unknown = set(value) - {"min", "max", "num", "log"}
        if unknown or "min" not in value or "max" not in value:
            raise InputError(where, "a range is {min = …, max = …, num = … (grid), log = true|false}")
        lo, hi, log_scale = float(value["min"]), float(value["max"]), bool(value.get("log", False))
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi) or (log_scale and lo <= 0):
            raise InputError(where, f"needs finite min ≤ max (> 0 on a log scale), got {value!r}")
        if not grid:
            return {"min": lo, "max": hi, "log": float(log_scale)}
        num = value.get("num")
        if not isinstance(num, int) or isinstance(num, bool) or num < 1:
            raise InputError(f"{where}.num", f"a grid range needs an integer num ≥ 1, got {num!r}")
        _check_point_count(f"{where}.num", num)
        space = np.geomspace if log_scale else np.linspace
        return [float(v) for v in space(lo, hi, num)]
    return [value]


def _check_point_count(field: str, count: int, detail: str = "") -> None:
    """Refuse (InputError naming ``field``) more than :data:`MAX_POINTS` points."""
    if count > MAX_POINTS:
        raise InputError(
            field,
            f"{count:,} points{detail} would need ~{count * _BYTES_PER_POINT / 2**30:.3g} GiB, more than "
            f"the {MEMORY_BUDGET_BYTES // 2**30} GiB memory budget (at most {MAX_POINTS:,} points)",
        )


def _check_evaluation_memory(
    field: str, settings: SweepSettings, axes: dict[str, Any], count: int, chunk_size: int
) -> None:
    """Refuse ``periods`` whose single evaluation would not fit the memory budget.

    Plant: one point at a time, (periods + 1) periods sampled at 100 kS/s, the lowest
    frequency the amplifier accepts costing most.  Ideal: a chunk's rows at once,
    2 intervals a period (401 with a half-cosine flyback).  Per process: each Dask
    worker evaluates one chunk at a time.
    """
    periods = settings.periods
    if settings.model == "plant":
        freq = axes["frequency_hz"]
        floor = settings.amplifier.min_frequency_hz  # lower ones fail the amplifier check, unrun
        runnable = [freq["min"]] if isinstance(freq, dict) else [f for f in freq if f >= floor]
        lowest = max(min(runnable, default=floor), floor)
        nbytes = (periods + 1) * round(DEFAULT_SAMPLE_RATE_HZ / lowest) * BYTES_PER_SAMPLE
        what = f"a {lowest:g} Hz plant point"
    else:
        rows = min(chunk_size, count)
        cosine = "half-cosine" in axes["flyback_shape"]
        intervals = COSINE_PIECES + 1 if cosine else 2
        nbytes = rows * intervals * periods * BYTES_PER_SAMPLE
        what = f"an ideal-model chunk of {rows} point{'' if rows == 1 else 's'}"
        what += " (half-cosine)" if cosine else ""
    if nbytes > MEMORY_BUDGET_BYTES:
        raise InputError(
            field,
            f"{periods} periods of {what} would need ~{nbytes / 2**30:.3g} GiB, more than the "
            f"{MEMORY_BUDGET_BYTES // 2**30} GiB memory budget",
        )


def _check(name: str, value: Any, where: str) -> Any:
    if name in _TEXT:
        if not isinstance(value, str):
            raise InputError(where, f"must be a string, got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(where, f"must be a number, got {value!r}")
    if name in _INTEGER:
        if int(value) != value:
            raise InputError(where, f"must be an integer, got {value!r}")
        return int(value)
    return float(value)


def load_spec(path: Path | str) -> SweepSpec:
    """Read and expand a sweep spec; every problem is an :class:`InputError` naming file and field."""
    path = Path(path)
    data = read_toml(path)
    unknown = set(data) - {"sweep", "parameters"}
    if unknown:
        raise InputError(f"{path}: [{sorted(unknown)[0]}]", "unknown table; known: [sweep], [parameters]")
    head = data.get("sweep", {})
    params = data.get("parameters", {})
    if not isinstance(head, dict) or not isinstance(params, dict):
        raise InputError(str(path), "[sweep] and [parameters] must be tables")
    known = {"model", "periods", "amplifier", "sample", "chunk_size", "points", "seed"}
    for key in head:
        if key not in known:
            raise InputError(f"{path}: [sweep].{key}", f"unknown field; known: {', '.join(sorted(known))}")
    model = head.get("model", "plant")
    if model not in MODELS:
        raise InputError(f"{path}: [sweep].model", f"expected one of {', '.join(MODELS)}, got {model!r}")
    periods = head.get("periods", 5)
    if not isinstance(periods, int) or isinstance(periods, bool) or not 1 <= periods <= MAX_PERIODS:
        raise InputError(f"{path}: [sweep].periods", f"must be an integer 1–{MAX_PERIODS}, got {periods!r}")
    chunk_size = head.get("chunk_size", 50)
    if not isinstance(chunk_size, int) or isinstance(chunk_size, bool) or chunk_size < 1:
        raise InputError(f"{path}: [sweep].chunk_size", f"must be an integer ≥ 1, got {chunk_size!r}")
    amp_spec = head.get("amplifier", "firmware_sim")
    if not isinstance(amp_spec, str):
        raise InputError(f"{path}: [sweep].amplifier", f"must be a string, got {amp_spec!r}")
    if amp_spec not in ("anc300", "firmware_sim", "paper") and not Path(amp_spec).is_absolute():
        amp_spec = str(path.parent / amp_spec)
    amp_model, amplifier = resolve_amplifier(amp_spec, f"{path}: [sweep].amplifier")
    settings = SweepSettings(model, periods, amp_model, amplifier)
    sample = head.get("sample", "grid")
    if sample not in ("grid", "random"):
        raise InputError(f"{path}: [sweep].sample", f"expected grid or random, got {sample!r}")
    for key in params:
        if key not in DEFAULTS:
            raise InputError(
                f"{path}: [parameters].{key}", f"unknown parameter; known: {', '.join(DEFAULTS)}"
            )
    grid = sample == "grid"
    axes = {name: _values(name, params.get(name, DEFAULTS[name]), f"{path}: [parameters].{name}", grid)
            for name in DEFAULTS}  # fmt: skip
    for name, values in axes.items():
        if isinstance(values, list):
            axes[name] = [_check(name, v, f"{path}: [parameters].{name}") for v in values]
    # the sizes first: nothing is expanded before the point count and periods are known to fit
    if grid:
        count = math.prod(len(axes[name]) for name in DEFAULTS)
        sizes = " × ".join(f"{len(axes[name])} {name}" for name in DEFAULTS if len(axes[name]) > 1)
        _check_point_count(f"{path}: [parameters]", count, f" ({sizes})")
    else:
        wanted = head.get("points")
        if not isinstance(wanted, int) or isinstance(wanted, bool) or wanted < 1:
            raise InputError(
                f"{path}: [sweep].points", f"random sampling needs an integer ≥ 1, got {wanted!r}"
            )
        count = wanted
        _check_point_count(f"{path}: [sweep].points", count)
        seed = head.get("seed", 0)
        if not isinstance(seed, int) or isinstance(seed, bool):
            raise InputError(f"{path}: [sweep].seed", f"must be an integer, got {seed!r}")
    _check_evaluation_memory(f"{path}: [sweep].periods", settings, axes, count, chunk_size)
    if grid:
        lists = [axes[name] for name in DEFAULTS]
        points = [dict(zip(DEFAULTS, combo, strict=True)) for combo in itertools.product(*lists)]
    else:
        points = _random_points(axes, count, seed)
    _check_text_values(points, path)
    return SweepSpec(settings, points, chunk_size)


def _random_points(axes: dict[str, Any], count: int, seed: int) -> list[dict[str, Any]]:
    rng = np.random.default_rng(seed)
    columns: dict[str, list[Any]] = {}
    for name, values in axes.items():
        if isinstance(values, dict):
            lo, hi = values["min"], values["max"]
            if values["log"]:
                draws = np.exp(rng.uniform(math.log(lo), math.log(hi), count))
            else:
                draws = rng.uniform(lo, hi, count)
            columns[name] = [float(v) for v in draws]
        else:
            picks = rng.integers(0, len(values), count)
            columns[name] = [values[int(k)] for k in picks]
    return [{name: columns[name][i] for name in axes} for i in range(count)]


def _check_text_values(points: list[dict[str, Any]], path: Path) -> None:
    for name, check in (("flyback_shape", lambda v: v in FLYBACK_SHAPES), ("part", _part_ok),
                        ("support", lambda v: v in Support.KINDS)):  # fmt: skip
        for value in {p[name] for p in points}:
            if not check(value):
                raise InputError(f"{path}: [parameters].{name}", f"bad value {value!r}")
    for value in {p["surface"] for p in points}:
        if value != "embedded":
            load_surface(Path(value))  # InputError naming the file if it does not load


def _part_ok(text: str) -> bool:
    try:
        Part.parse(text)
    except InputError:
        return False
    return True
