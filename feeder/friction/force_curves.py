"""Friction force curves: the CSV format and the static-friction analysis (paper §IV.B, Figs. 7, 10, 11).

**CSV format** (UTF-8, comma separated, one header row; ``#`` lines are comments)::

    # cantilever = TL-FM              optional metadata, "key = value"
    # stiffness_n_per_m = 2.08        (either; a command-line stiffness wins)
    displacement_m,deflection_m
    0.0,1.5012e-07
    ...

Columns: ``displacement_m`` (support position, m) and either ``deflection_m`` (cantilever
deflection, m; force = stiffness × deflection) or ``force_n`` (N). Other columns are
ignored. Rows are in recording (time) order; every value must be a finite number.

**Analysis** (force F = k·deflection, samples in time order, n samples):

1. *Baseline*: a straight line F(x) is fitted to the first ``baseline_fraction`` of the
   samples (free approach, before contact) and subtracted everywhere, removing offset
   and drift; the noise σ is 1.4826 × the median absolute residual there.
2. *Smoothing*: moving average over w = max(5, n/100) samples (odd), σ_w = σ/√w.
3. *Slip*: the first sample where the smoothed force has fallen below its running
   maximum M by more than max(``drop_fraction``·M, 6σ_w), with M > 10σ_w. No such
   sample → the part never slid, no static-friction peak.
4. *Static-friction peak*: p = argmax of the smoothed force before the slip. A quadratic
   F(x) is fitted to the raw samples from where the smoothed force first reaches half its
   maximum up to the last stuck sample s (the last sample after p still within 4σ of the
   loading fit). The peak is the fitted force at x_s: the noise is averaged over the
   whole loading branch instead of picking the noisiest sample.
5. *Contact onset*: the displacement where a straight line fitted to the loading samples
   between 10 % and 50 % of the peak crosses zero.
6. *Sliding level*: median (and std) of the force from w samples after the slip until the
   smoothed force first drops below 25 % of the peak (end of the curve or retraction).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from feeder.errors import InputError
from feeder.files import write_text
from feeder.friction.cantilevers import cantilever_stiffness

DISPLACEMENT = "displacement_m"
DEFLECTION = "deflection_m"
FORCE = "force_n"


@dataclass(frozen=True)
class ForceCurve:
    """One recorded curve: support displacement (m) and force on the cantilever (N)."""

    displacement_m: np.ndarray
    force_n: np.ndarray
    source: str
    stiffness_n_per_m: float | None = None
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class FrictionPeak:
    """What one force curve says (SI units; forces with the baseline removed)."""

    source: str
    static_friction_n: float
    peak_displacement_m: float
    contact_onset_m: float
    sliding_force_n: float
    sliding_force_std_n: float
    noise_n: float
    baseline_offset_n: float
    baseline_slope_n_per_m: float
    slip_index: int

    def corrected_force_n(self, curve: ForceCurve) -> np.ndarray:
        """The curve's force with this analysis' baseline (offset + drift) removed."""
        x = curve.displacement_m
        return curve.force_n - (self.baseline_offset_n + self.baseline_slope_n_per_m * (x - x[0]))


@dataclass(frozen=True)
class FrictionSummary:
    """Several curves: mean static friction and its spread (sample std, ddof = 1)."""

    count: int
    mean_static_friction_n: float
    static_friction_std_n: float
    static_friction_sem_n: float
    min_static_friction_n: float
    max_static_friction_n: float
    mean_sliding_force_n: float


def read_force_curve(path: Path, stiffness_n_per_m: float | None = None) -> ForceCurve:
    """Read a force-curve CSV (module docstring). ``stiffness_n_per_m`` overrides the file's."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(str(path), "no such file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(str(path), f"cannot read: {err}") from None
    metadata: dict[str, str] = {}
    rows: list[tuple[int, list[str]]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            key, sep, entry = stripped[1:].partition("=")
            if sep:
                metadata[key.strip().lower()] = entry.strip()
            continue
        rows.append((number, next(csv.reader([stripped]))))
    if not rows:
        raise InputError(str(path), "no header row (expected displacement_m and deflection_m or force_n)")
    header = [h.strip() for h in rows[0][1]]
    if DISPLACEMENT not in header or not ({DEFLECTION, FORCE} & set(header)):
        raise InputError(
            str(path),
            f"missing column: need {DISPLACEMENT} and {DEFLECTION} or {FORCE}, found {', '.join(header)}",
        )
    y_name = FORCE if FORCE in header else DEFLECTION
    x_col, y_col = header.index(DISPLACEMENT), header.index(y_name)
    values = np.empty((len(rows) - 1, 2))
    for k, (number, fields) in enumerate(rows[1:]):
        for j, (col, name) in enumerate(((x_col, DISPLACEMENT), (y_col, y_name))):
            cell = fields[col].strip() if col < len(fields) else ""
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise InputError(str(path), f"line {number}: {name} is {cell!r}, not a finite number")
            values[k, j] = value
    if values.shape[0] < 50:
        raise InputError(str(path), f"only {values.shape[0]} samples; a force curve needs at least 50")
    try:
        file_stiffness = float(metadata["stiffness_n_per_m"]) if "stiffness_n_per_m" in metadata else None
    except ValueError:
        raise InputError(str(path), "metadata stiffness_n_per_m is not a number") from None
    recorded = cantilever_stiffness(metadata.get("cantilever"), file_stiffness)
    stiffness = recorded if stiffness_n_per_m is None else stiffness_n_per_m
    warnings: tuple[str, ...] = ()
    overridden = (
        stiffness is not None and recorded is not None and not math.isclose(stiffness, recorded, rel_tol=0.01)
    )
    if y_name == DEFLECTION and overridden:
        named = metadata.get("cantilever") or "stiffness_n_per_m"
        warnings = (f"{path.name}: read with {stiffness:g} N/m, but its header records {recorded:g} N/m "
                    f"({named}): the forces scale with it",)  # fmt: skip
    if y_name == FORCE:
        return ForceCurve(values[:, 0], values[:, 1], str(path), stiffness)
    if stiffness is None:
        raise InputError("--stiffness", f"{path.name} records deflection: give --cantilever or --stiffness")
    return ForceCurve(values[:, 0], stiffness * values[:, 1], str(path), stiffness, warnings)


def write_force_curve(
    path: Path, displacement_m: np.ndarray, deflection_m: np.ndarray, metadata: dict[str, str]
) -> None:
    """Write a curve in the CSV format above (metadata as ``# key = value`` lines), atomically."""
    lines = [f"# {key} = {value}" for key, value in metadata.items()]
    lines.append(f"{DISPLACEMENT},{DEFLECTION}")
    lines += [f"{x:.6e},{d:.6e}" for x, d in zip(displacement_m, deflection_m, strict=True)]
    write_text(path, "\n".join(lines) + "\n")


def _moving_average(values: np.ndarray, window: int) -> np.ndarray:
    padded = np.pad(values, window // 2, mode="edge")
    cumulative = np.concatenate(([0.0], np.cumsum(padded)))
    return (cumulative[window:] - cumulative[:-window]) / window


def analyse_force_curve(
    curve: ForceCurve, baseline_fraction: float = 0.2, drop_fraction: float = 0.05
) -> FrictionPeak:
    """Contact onset, static-friction peak and sliding level of one curve (module docstring).

    Two passes: the first uses the first ``baseline_fraction`` of the samples as baseline,
    the second the whole free approach (up to one smoothing window before the force
    leaves the baseline noise), which pins the drift down better at the peak.
    """
    if not 0.05 <= baseline_fraction <= 0.6:
        raise InputError("--baseline-fraction", f"must lie in [0.05, 0.6], got {baseline_fraction!r}")
    n = curve.force_n.size
    first_pass, free_end = _analyse(curve, max(int(baseline_fraction * n), 10), drop_fraction)
    if free_end <= max(int(baseline_fraction * n), 10):
        return first_pass
    return _analyse(curve, free_end, drop_fraction)[0]


def _analyse(curve: ForceCurve, nb: int, drop_fraction: float) -> tuple[FrictionPeak, int]:
    """One pass with the first ``nb`` samples as baseline; also returns where contact begins."""
    x, raw = curve.displacement_m, curve.force_n
    n = x.size
    source = curve.source
    base_coef = np.polyfit(x[:nb], raw[:nb], 1)
    force = raw - np.polyval(base_coef, x)
    residual = force[:nb]
    sigma = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
    sigma = max(sigma, 1e-12 * float(np.max(np.abs(raw))) + 1e-30)
    window = max(5, n // 100) | 1
    smooth = _moving_average(force, window)
    sigma_w = sigma / math.sqrt(window)
    running = np.maximum.accumulate(smooth)
    fallen = (running - smooth > np.maximum(drop_fraction * running, 6 * sigma_w)) & (running > 10 * sigma_w)
    if not np.any(smooth > 10 * sigma_w):
        raise InputError(source, "no contact: the force never rises clearly above the baseline noise")
    if not np.any(fallen):
        raise InputError(source, "no slip: the force never drops after its peak (no static-friction peak)")
    slip = int(np.argmax(fallen))
    peak_index = int(np.argmax(smooth[:slip]))
    provisional = float(smooth[peak_index])
    half = int(np.argmax(smooth[: peak_index + 1] >= 0.5 * provisional))
    if half < nb:
        raise InputError(
            source,
            f"contact starts inside the baseline segment (first {nb} samples); "
            "record a longer free approach or lower --baseline-fraction",
        )
    if peak_index - half < 8:
        raise InputError(source, "too few samples on the loading branch to fit the peak")
    fit = np.polyfit(x[half : peak_index + 1], force[half : peak_index + 1], 2)
    # last stuck sample: CUSUM of (residual + 3σ) after the smoothed peak, maximal at the slip
    stop_search = min(slip + window, n)
    after = force[peak_index + 1 : stop_search] - np.polyval(fit, x[peak_index + 1 : stop_search])
    cusum = np.cumsum(after + 3 * sigma)
    last = peak_index + 1 + int(np.argmax(cusum)) if cusum.size and cusum.max() > 0 else peak_index
    peak = float(np.polyval(fit, x[last]))
    tenth = nb + int(np.argmax(smooth[nb : half + 1] >= 0.1 * peak))
    at_baseline = np.nonzero(smooth[:tenth] <= 3 * sigma_w)[0]
    free_end = int(at_baseline[-1]) - window if at_baseline.size else 0
    onset = _onset(x, force, tenth, half)
    end = slip + window
    below = np.nonzero(smooth[end:] < 0.25 * peak)[0]
    stop = end + int(below[0]) if below.size else n
    sliding = force[end:stop]
    result = FrictionPeak(
        source=source,
        static_friction_n=peak,
        peak_displacement_m=float(x[last]),
        contact_onset_m=onset,
        sliding_force_n=float(np.median(sliding)) if sliding.size else math.nan,
        sliding_force_std_n=float(np.std(sliding)) if sliding.size > 1 else math.nan,
        noise_n=sigma,
        baseline_offset_n=float(np.polyval(base_coef, x[0])),
        baseline_slope_n_per_m=float(base_coef[0]),
        slip_index=last + 1,
    )
    return result, free_end


def _onset(x: np.ndarray, force: np.ndarray, tenth: int, half: int) -> float:
    """Zero crossing of a line through the loading samples between 10 % and 50 % of the peak."""
    if half - tenth < 3:
        return float(x[tenth])
    slope, intercept = np.polyfit(x[tenth : half + 1], force[tenth : half + 1], 1)
    return float(-intercept / slope) if slope != 0 else float(x[tenth])


def summarize(peaks: Sequence[FrictionPeak]) -> FrictionSummary:
    """Mean static friction of several curves and its spread."""
    forces = np.array([p.static_friction_n for p in peaks])
    count = forces.size
    std = float(np.std(forces, ddof=1)) if count > 1 else 0.0
    sliding = [p.sliding_force_n for p in peaks if math.isfinite(p.sliding_force_n)]
    return FrictionSummary(
        count=count,
        mean_static_friction_n=float(forces.mean()),
        static_friction_std_n=std,
        static_friction_sem_n=std / math.sqrt(count),
        min_static_friction_n=float(forces.min()),
        max_static_friction_n=float(forces.max()),
        mean_sliding_force_n=float(np.mean(sliding)) if sliding else math.nan,
    )
