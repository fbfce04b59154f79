"""Waveform design: the best sawtooth an amplifier can play for a part, and design files.

API for scripts::

    from feeder.design import DesignProblem, design_waveform, write_design
    from feeder.parts import Part
    from feeder.plant.amplifier import resolve_amplifier
    model, limits = resolve_amplifier("paper")            # or "anc300", or "my-amp.toml"
    problem = DesignProblem(Part.parse("500x500x50"), amplifier_model=model, amplifier=limits)
    design = design_waveform(problem, objective="max-step")   # full plant model, ~10–60 s
    design.waveform, design.predicted_step_m, design.predicted_step_band_m, design.margins
    write_design("design.toml", problem, design.waveform, design.prediction, design.tables())
    problem.predict(waveform)          # StepPrediction of any waveform (plant model, τ and F_k/F_s band)

The family searched (all sawtooths the amplifier can play):

- ``current-limited``: the command drops at once; the current limit into the
  stack capacitance sets the flyback, t_f ≈ C·ΔV/I_max (DESIGN §4);
- ``linear`` and ``half-cosine`` flybacks of a commanded duration no shorter
  than the amplifier can follow (ΔV/t_f, resp. π·ΔV/(2 t_f), within
  min(slew, I_max/C)); for a table amplifier (ANC300: 256 points per period)
  the duration is a whole number of table steps;
- frequency within the amplifier's range (from :data:`MIN_SEARCH_FREQUENCY_HZ`:
  slower sawtooths step no further per period and cost more to simulate),
  amplitude up to the rail; the rise lasts at least
  :data:`feeder.planner.RISE_PER_FLYBACK` flybacks (the part re-sticks early).

Objectives: ``max-step`` (largest step per period), ``max-speed`` (largest
step × frequency), ``min-scatter`` (smallest relative width of the predicted
band (τ ± band, F_k/F_s ± spread) among designs whose whole band moves).
Every candidate is scored with the full plant model
(:func:`feeder.planner.plant_step`: amplifier limits, stack dynamics, exact
stick-slip), first on a coarse grid, then refined with Nelder–Mead
(``scipy.optimize.minimize``) from the best grid points.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize

from feeder.contact.breakaway import ContactResult, contact
from feeder.errors import InputError
from feeder.parts import FLAT, Part, Support
from feeder.planner import RISE_PER_FLYBACK, StepPrediction, flyback_time_s, plant_step
from feeder.plant.amplifier import AMPLIFIER_MODELS, AmplifierLimits, amplifier_table
from feeder.plant.plant import run_waveform
from feeder.plant.stack import StackParameters
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO, Friction, kinetic_ratio_band
from feeder.surface.parameters import DEFAULT_SURFACE, SurfaceParameters
from feeder.waveform import ANC300_TABLE_POINTS, FLYBACK_SHAPES, Waveform, write_waveform_file

log = logging.getLogger(__name__)

OBJECTIVES = ("max-step", "min-scatter", "max-speed")
MIN_SEARCH_FREQUENCY_HZ = 10.0
VERIFY_PERIODS = 50
"""Periods of the check run (the ``feeder simulate --periods 50`` the design must agree with)."""
TABLE_POINTS: dict[str, int] = {"anc300": ANC300_TABLE_POINTS}
"""Waveform table length per amplifier model (flyback durations in whole table steps)."""
GRID_POINTS = (7, 8)
"""Default coarse grid: frequencies (log-spaced) × amplitudes, per flyback duration and shape."""
REFINE_EVALUATIONS = 70
"""Default plant evaluations per Nelder–Mead refinement (three refinements)."""
_GRID_FLYBACKS = (1.0, 1.6, 2.5)
"""Commanded flyback durations on the grid, as multiples of the fastest the amplifier follows."""
_STARTS = 3


@dataclass(frozen=True)
class DesignProblem:
    """What a waveform is designed for (SI units): part on support, friction, amplifier, stack.

    surface_label: how the surface is named in design files (a path, or ``embedded``).
    """

    part: Part
    support: Support = FLAT
    surface: SurfaceParameters = DEFAULT_SURFACE
    surface_label: str = "embedded"
    tau_pa: float | None = None
    tau_band_pa: float | None = None
    kinetic_ratio: float = DEFAULT_KINETIC_RATIO
    amplifier_model: str = "firmware_sim"
    amplifier: AmplifierLimits = field(default_factory=lambda: AMPLIFIER_MODELS["firmware_sim"])
    stack: StackParameters = field(default_factory=StackParameters)
    tau_adhesion_work_j_m2: float | None = None
    """The w a given τ was fitted with (None: τ is the one fitted with the surface's w, see contact)."""

    def contact(self) -> ContactResult:
        """The contact model's result (τ resolved with the surface's w)."""
        return contact(self.part, support=self.support, surface=self.surface, tau_pa=self.tau_pa,
                       tau_band_pa=self.tau_band_pa,
                       tau_adhesion_work_j_m2=self.tau_adhesion_work_j_m2)  # fmt: skip

    def breakaway_accel_m_s2(self) -> tuple[float, tuple[float, float]]:
        """a_s = τ·A_r/m and its band (m/s²) from the contact model."""
        result = self.contact()
        return result.breakaway_accel_m_s2, result.breakaway_accel_band_m_s2

    def step_m(self, waveform: Waveform, static_accel_m_s2: float, kinetic_ratio: float) -> float:
        """Steady step (m, signed) in the full plant model."""
        return plant_step(waveform, static_accel_m_s2, kinetic_ratio, self.amplifier, self.stack)

    def predict(self, waveform: Waveform) -> StepPrediction:
        """Step and band: τ's band × F_k/F_s ± spread, in the full plant model."""
        a_s, (a_lo, a_hi) = self.breakaway_accel_m_s2()
        return self._predict(waveform, a_s, a_lo, a_hi)

    def _predict(self, waveform: Waveform, a_s: float, a_lo: float, a_hi: float) -> StepPrediction:
        r_lo, r_hi = kinetic_ratio_band(self.kinetic_ratio)
        nominal = self.step_m(waveform, a_s, self.kinetic_ratio)
        ends = (self.step_m(waveform, a_hi, r_hi), self.step_m(waveform, a_lo, r_lo))
        return StepPrediction(nominal, (min(*ends, nominal), max(*ends, nominal)))

    def prediction_table(self, prediction: StepPrediction, written_by: str) -> dict[str, Any]:
        """The ``[prediction]`` table of a design file."""
        result = self.contact()
        a_s, band = result.breakaway_accel_m_s2, result.breakaway_accel_band_m_s2
        return {
            "written_by": written_by,
            "part": self.part.label,
            "density_kg_m3": self.part.density_kg_m3,
            "support": self.support.kind,
            "surface": self.surface_label,
            "tau_pa": result.tau_pa,
            "tau_band_pa": result.tau_band_pa,
            "tau_adhesion_work_j_m2": result.tau_adhesion_work_j_m2,
            "adhesion_work_j_m2": self.surface.adhesion_work_j_m2,
            "kinetic_ratio": self.kinetic_ratio,
            "breakaway_accel_m_s2": a_s,
            "breakaway_accel_band_m_s2": list(band),
            "model": "plant",
            "predicted_step_m": prediction.step_m,
            "predicted_step_band_m": list(prediction.band_m),
        }


def write_design(
    path: Path | str,
    problem: DesignProblem,
    waveform: Waveform,
    prediction: StepPrediction,
    extra_tables: dict[str, dict[str, Any]] | None = None,
    written_by: str = "feeder.design",
) -> None:
    """Write ``waveform`` with the prediction it was made with, atomically (a design file).

    Tables: ``[waveform]``, ``[amplifier]``, ``[stack]``, ``[prediction]`` and ``extra_tables``.
    """
    tables = {
        "amplifier": amplifier_table(problem.amplifier_model, problem.amplifier),
        "stack": asdict(problem.stack),
        "prediction": problem.prediction_table(prediction, written_by),
        **(extra_tables or {}),
    }
    comment = (f"{written_by}: part {problem.part.label} µm on {problem.support.kind} support, "
               f"amplifier {problem.amplifier_model}; predicted step "
               f"{prediction.step_m * 1e6:.4g} µm per period (plant model)")  # fmt: skip
    write_waveform_file(path, waveform, tables, comment)


@dataclass(frozen=True)
class Design:
    """The best waveform found for an objective, with its prediction, margins and check run."""

    objective: str
    waveform: Waveform
    prediction: StepPrediction
    margins: dict[str, float]
    verified_step_mean_m: float
    evaluations: int
    table_points: int | None = None

    @property
    def predicted_step_m(self) -> float:
        return self.prediction.step_m

    @property
    def predicted_step_band_m(self) -> tuple[float, float]:
        return self.prediction.band_m

    @property
    def speed_m_s(self) -> float:
        return self.prediction.step_m * self.waveform.frequency_hz

    def tables(self) -> dict[str, dict[str, Any]]:
        """``[design]`` and ``[margins]`` tables of the design file."""
        design = {"objective": self.objective, "speed_m_s": self.speed_m_s,
                  "verified_periods": VERIFY_PERIODS,
                  "verified_step_mean_m": self.verified_step_mean_m,
                  "evaluations": self.evaluations, "table_points": self.table_points}  # fmt: skip
        return {"design": design, "margins": dict(self.margins)}

    def to_json(self) -> dict[str, Any]:
        w = self.waveform
        return {
            "objective": self.objective,
            "frequency_hz": w.frequency_hz,
            "amplitude_vpp": w.amplitude_vpp,
            "offset_v": w.offset_v,
            "flyback_shape": w.flyback_shape,
            "flyback_s": w.flyback_s,
            "direction": w.direction,
            "predicted_step_m": self.predicted_step_m,
            "predicted_step_band_m": list(self.predicted_step_band_m),
            "speed_m_s": self.speed_m_s,
            "verified_step_mean_m": self.verified_step_mean_m,
            "verified_periods": VERIFY_PERIODS,
            "margins": dict(self.margins),
            "evaluations": self.evaluations,
            "table_points": self.table_points,
        }


def fastest_flyback_s(shape: str, amplitude_vpp: float, amplifier: AmplifierLimits,
                      stack: StackParameters) -> float:  # fmt: skip
    """Shortest commanded flyback the amplifier follows: ΔV/r (linear), π·ΔV/(2r) (half-cosine)."""
    peak = math.pi / 2 if shape == "half-cosine" else 1.0
    return peak * amplitude_vpp / amplifier.max_slope_v_per_s(stack.capacitance_f)


def effective_flyback_s(waveform: Waveform, amplifier: AmplifierLimits, stack: StackParameters) -> float:
    """The flyback the plate sees: current-limited (bounded by the stack's response), or commanded."""
    if waveform.flyback_shape == "current-limited":
        return float(flyback_time_s(waveform.amplitude_vpp, waveform.frequency_hz, amplifier, stack)[0])
    return waveform.command_flyback_s


def margins(waveform: Waveform, problem: DesignProblem) -> dict[str, float]:
    """How far the design is from each limit (ratios ≥ 1 are inside; SI values beside them).

    flyback_margin: flyback acceleration S(1/t_r + 1/t_f)/t_f over a_break's upper end;
    ramp_margin: a_break's lower end over the ramp acceleration 2S/t_r²;
    current_margin: I_max over the current the flyback draws C·ΔV/t_f (1 when current-limited);
    rail_margin_v, frequency_margin: headroom to the rail and to the highest frequency.
    """
    amp, stack = problem.amplifier, problem.stack
    _, (a_lo, a_hi) = problem.breakaway_accel_m_s2()
    t_f = effective_flyback_s(waveform, amp, stack)
    t_r = waveform.period_s - t_f
    swing = waveform.amplitude_vpp
    if waveform.flyback_shape == "current-limited":
        swing *= 1.0 - t_f * waveform.frequency_hz
    stroke = stack.gain_m_per_v * swing
    fly = stroke * (1 / t_r + 1 / t_f) / t_f
    ramp = 2 * stroke / t_r**2
    peak = math.pi / 2 if waveform.flyback_shape == "half-cosine" else 1.0
    current = stack.capacitance_f * peak * swing / t_f
    return {
        "flyback_s": t_f,
        "rise_s": t_r,
        "stroke_m": stroke,
        "flyback_accel_m_s2": fly,
        "flyback_margin": fly / a_hi,
        "ramp_accel_m_s2": ramp,
        "ramp_margin": a_lo / ramp,
        "flyback_current_a": min(current, amp.current_limit_a),
        "current_margin": max(1.0, amp.current_limit_a / current),
        "rail_margin_v": amp.v_max_v - waveform.max_voltage_v,
        "frequency_margin": amp.max_frequency_hz / waveform.frequency_hz,
    }


class _Search:
    """Scores candidates (x = [log10 f, amplitude/rail, log(t_f/t_fastest)]) for one shape."""

    def __init__(self, problem: DesignProblem, objective: str, table_points: int | None) -> None:
        self.problem = problem
        self.objective = objective
        self.table_points = table_points
        self.a_s, (self.a_lo, self.a_hi) = problem.breakaway_accel_m_s2()
        amp = problem.amplifier
        self.f_lo = math.log10(max(amp.min_frequency_hz, min(MIN_SEARCH_FREQUENCY_HZ, amp.max_frequency_hz)))
        self.f_hi = math.log10(amp.max_frequency_hz)
        self.evaluations = 0

    def waveform(self, shape: str, x: np.ndarray) -> Waveform | None:
        """The candidate at x, or None if outside the family (bounds, rise ≥ k flybacks)."""
        amp, stack = self.problem.amplifier, self.problem.stack
        log_f, v_frac, log_t = (float(v) for v in x)
        if not (self.f_lo - 1e-12 <= log_f <= self.f_hi + 1e-12 and 0.02 <= v_frac <= 1.0):
            return None
        f = amp.settable_hz(10**log_f)
        volts = v_frac * amp.max_amplitude_vpp
        if shape == "current-limited":
            t_f = float(flyback_time_s(volts, f, amp, stack)[0])
            wave = Waveform(frequency_hz=f, amplitude_vpp=volts, offset_v=amp.v_min_v)
        else:
            if log_t < 0:
                return None
            t_f = fastest_flyback_s(shape, volts, amp, stack) * math.exp(log_t)
            if self.table_points:
                step = 1.0 / (self.table_points * f)
                t_f = step * max(1, math.ceil(t_f / step - 1e-9))
            if t_f >= 0.5 / f:
                return None
            wave = Waveform(frequency_hz=f, amplitude_vpp=volts, offset_v=amp.v_min_v,
                            flyback_shape=shape, flyback_s=t_f)  # fmt: skip
        if 1.0 / f - t_f < RISE_PER_FLYBACK * t_f:
            return None
        return wave

    def score(self, wave: Waveform) -> float:
        """Lower is better; 0 when the part does not move (or its band does not, for min-scatter)."""
        p = self.problem
        self.evaluations += 1
        step = p.step_m(wave, self.a_s, p.kinetic_ratio)
        if self.objective == "max-step":
            return -step
        if self.objective == "max-speed":
            return -step * wave.frequency_hz
        if step <= 0:
            return 0.0
        self.evaluations += 2
        band = p._predict(wave, self.a_s, self.a_lo, self.a_hi).band_m
        if band[0] <= 0:
            return 0.0
        return -1.0 / (1.0 + (band[1] - band[0]) / step)  # relative band width w → −1/(1+w)

    def objective_at(self, shape: str, x: np.ndarray) -> float:
        wave = self.waveform(shape, x)
        return 1.0 if wave is None else self.score(wave)


def design_waveform(
    problem: DesignProblem,
    objective: str = "max-step",
    *,
    table_points: int | None = None,
    shapes: tuple[str, ...] = FLYBACK_SHAPES,
    progress: Callable[[str], None] | None = None,
    grid_points: tuple[int, int] = GRID_POINTS,
    refine_evaluations: int = REFINE_EVALUATIONS,
) -> Design:
    """The best waveform for ``objective`` within ``problem.amplifier`` (full plant model).

    table_points: waveform table length (flyback in whole table steps); default
    :data:`TABLE_POINTS` for the amplifier model (256 for ``anc300``).
    progress: called with one-line messages (the CLI prints them on stderr).
    grid_points, refine_evaluations: search effort (smaller: faster, coarser).
    """
    if objective not in OBJECTIVES:
        raise InputError("objective", f"expected one of {', '.join(OBJECTIVES)}, got {objective!r}")
    unknown = [s for s in shapes if s not in FLYBACK_SHAPES]
    if unknown or not shapes:
        raise InputError("shapes", f"expected some of {', '.join(FLYBACK_SHAPES)}, got {shapes!r}")
    if table_points is None:
        table_points = TABLE_POINTS.get(problem.amplifier_model)
    say = progress or (lambda message: log.info("%s", message))
    search, ranked = ranked_search(problem, objective, table_points, shapes, say, grid_points,
                                    refine_evaluations)  # fmt: skip
    wave = ranked[0][1]
    say(
        f"best: {wave.flyback_shape}, {wave.frequency_hz:.5g} Hz, {wave.amplitude_vpp:.5g} Vpp; "
        f"checking over {VERIFY_PERIODS} periods"
    )
    prediction = problem._predict(wave, search.a_s, search.a_lo, search.a_hi)
    check = run_waveform(Friction(search.a_s, problem.kinetic_ratio), wave, VERIFY_PERIODS,
                         problem.amplifier, problem.stack)  # fmt: skip
    return Design(
        objective=objective,
        waveform=wave,
        prediction=prediction,
        margins=margins(wave, problem),
        verified_step_mean_m=float(np.mean(check.steps_m)),
        evaluations=search.evaluations + 3,
        table_points=table_points,
    )


def ranked_search(
    problem: DesignProblem,
    objective: str,
    table_points: int | None,
    shapes: tuple[str, ...],
    say: Callable[[str], None],
    grid_points: tuple[int, int],
    refine_evaluations: int,
) -> tuple[_Search, list[tuple[float, Waveform]]]:
    """Coarse grid, then Nelder–Mead from the best starts: (score, waveform) best first."""
    search = _Search(problem, objective, table_points)
    freqs = np.linspace(search.f_lo, search.f_hi, grid_points[0])
    volts = np.linspace(1.0 / grid_points[1], 1.0, grid_points[1])
    candidates: list[tuple[float, str, np.ndarray]] = []
    for shape in shapes:
        flybacks = [0.0] if shape == "current-limited" else [math.log(k) for k in _GRID_FLYBACKS]
        grid = [np.array([f, v, t]) for f in freqs for v in volts for t in flybacks]
        say(f"grid: {shape} flyback, {len(grid)} candidates")
        for x in grid:
            wave = search.waveform(shape, x)
            if wave is not None:
                candidates.append((search.score(wave), shape, x))
    if not candidates:
        raise InputError("amplifier", "no sawtooth within the amplifier's limits has a rise of "
                         f"{RISE_PER_FLYBACK:g} flybacks")  # fmt: skip
    candidates.sort(key=lambda c: c[0])
    if candidates[0][0] >= 0:
        raise InputError("design", "no waveform within the amplifier's limits moves the part "
                         "(for min-scatter: over its whole band)")  # fmt: skip
    best_score, best_shape, best_x = candidates[0]
    starts: list[tuple[float, str, np.ndarray]] = []
    for c in candidates:
        if len(starts) == _STARTS:
            break
        if c[0] < 0 and all(c[1] != s[1] or np.abs(c[2] - s[2]).max() > 0.2 for s in starts):
            starts.append(c)
    for k, (score, shape, x0) in enumerate(starts, 1):
        say(
            f"refine {k}/{len(starts)}: {shape} from {10 ** x0[0]:.4g} Hz, "
            f"{x0[1] * problem.amplifier.max_amplitude_vpp:.4g} Vpp (score {score:.4g})"
        )
        free = slice(0, 2) if shape == "current-limited" else slice(0, 3)

        def fun(y: np.ndarray, shape: str = shape, x0: np.ndarray = x0, free: slice = free) -> float:
            x = x0.copy()
            x[free] = y
            return search.objective_at(shape, x)

        step0 = np.array([0.08, 0.06, 0.15])[free]
        simplex = np.vstack([x0[free], x0[free] + np.diag(step0)])
        result = minimize(fun, x0[free], method="Nelder-Mead",
                          options={"initial_simplex": simplex, "maxfev": refine_evaluations,
                                   "xatol": 1e-4, "fatol": 1e-12})  # fmt: skip
        if result.fun < best_score:
            x = x0.copy()
            x[free] = result.x
            best_score, best_shape, best_x = float(result.fun), shape, x
    ranked = [(score, search.waveform(shape, x)) for score, shape, x in candidates if score < 0]
    best = search.waveform(best_shape, best_x)
    assert best is not None  # the best score is < 0, so the candidate is in the family
    ranked.append((best_score, best))
    ranked.sort(key=lambda c: c[0])
    return search, [(score, wave) for score, wave in ranked if wave is not None]
