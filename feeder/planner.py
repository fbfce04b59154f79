"""Acceleration planner: breakaway acceleration → waveform, step count, predicted step ± band.

API for other agents (feeder/daemon)
------------------------------------
::

    from feeder.planner import plan, predict_step, Plan, StepPrediction
    p = plan(part, support=FLAT, surface=DEFAULT_SURFACE, tau_pa=None,  # None: τ fitted with w
             amplifier=AmplifierLimits(), distance_m=500e-6)       # InputError if impossible
    p.waveform()            # feeder.waveform.Waveform to send (current-limited flyback)
    p.frequency_hz, p.amplitude_vpp, p.flyback_s, p.flyback_shape, p.direction, p.steps,
    p.predicted_step_m, p.predicted_step_band_m, p.duration_s,
    p.breakaway_accel_m_s2, p.margins, p.to_json()
    s = predict_step(waveform, part, support, surface, tau_pa)     # StepPrediction
    s.step_m, s.band_m      # signed: + for a forward waveform

Steps are predicted with the full plant model (:func:`feeder.plant.plant.run_waveform`:
amplifier limits, stack dynamics, exact stick-slip).  The band propagates τ's
band (a_s ∝ τ) and F_k/F_s ± :data:`~feeder.plant.stick_slip.KINETIC_RATIO_SPREAD`.

Margins (DESIGN §4, for a sawtooth of stroke S, rise t_r, flyback t_f):

- flyback acceleration ``S(1/t_r + 1/t_f)/t_f``: the plate's velocity reversal
  over the flyback; an ideal plate moves the part iff it exceeds a_k.  Required
  ≥ k·a_break at the *upper* end of the band (the part must break loose even
  if τ is high).  t_f is the current-limited flyback, but never shorter than
  the stack's response time 1/(2 f_n) + R_out·C.
- ramp acceleration ``2S/t_r²``: the constant acceleration that covers S in t_r
  from rest, a bound on how fast a rise may be (the ideal rise itself runs at
  constant velocity); required ≤ a_break/k at the *lower* end of the band.  It is
  not the plate's peak during the rise: the stack rings after each flyback (at
  the default 30 kHz, |a| up to tens of a_break for ~0.1–0.2 ms), which is left
  to the plant model: the step prediction includes it.

Choice: for each allowed frequency the amplitudes meeting both margins are
found on a grid (closed forms); the frequency with the shortest duration wins
(rise ≥ 4 flybacks so the part re-sticks early in the rise); the amplitude is
then solved with the plant model so that ``steps × step = distance``, on the
rising branch of step(amplitude) (smaller amplitude, smaller sensitivity to τ).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import brentq

from feeder.contact.breakaway import contact
from feeder.errors import InputError
from feeder.parts import FLAT, Part, Support
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.ideal_plate import linear_flyback_step
from feeder.plant.plant import run_waveform
from feeder.plant.stack import StackParameters
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO, Friction, kinetic_ratio_band
from feeder.surface.parameters import DEFAULT_SURFACE, SurfaceParameters
from feeder.waveform import Waveform

DEFAULT_MARGIN = 1.2
"""k: flyback acceleration ≥ k·a_break(upper), ramp acceleration ≤ a_break(lower)/k."""
RISE_PER_FLYBACK = 4.0
"""The rise lasts at least this many flybacks (re-stick and ringing settle early in the rise)."""
PREDICTION_PERIODS = 2
_AMPLITUDE_GRID = 96
_FREQUENCY_GRID = 40


@dataclass(frozen=True)
class StepPrediction:
    """Predicted displacement per step (m, + forward) and its band (low, high)."""

    step_m: float
    band_m: tuple[float, float]


@dataclass(frozen=True)
class Plan:
    """A planned move: the waveform, how many steps, and what to expect (SI units)."""

    distance_m: float
    frequency_hz: float
    amplitude_vpp: float
    flyback_s: float
    flyback_shape: str
    direction: str
    steps: int
    predicted_step_m: float
    predicted_step_band_m: tuple[float, float]
    predicted_distance_m: float
    predicted_distance_band_m: tuple[float, float]
    duration_s: float
    breakaway_accel_m_s2: float
    breakaway_accel_band_m_s2: tuple[float, float]
    margins: dict[str, float]
    warnings: tuple[str, ...] = field(default_factory=tuple)

    def waveform(self) -> Waveform:
        """The waveform to play ``steps`` times."""
        return Waveform(
            frequency_hz=self.frequency_hz,
            amplitude_vpp=self.amplitude_vpp,
            flyback_shape=self.flyback_shape,
            direction=self.direction,
        )

    def to_json(self) -> dict[str, Any]:
        """The ``feeder plan --json`` object."""
        return {
            "distance_m": self.distance_m,
            "frequency_hz": self.frequency_hz,
            "amplitude_vpp": self.amplitude_vpp,
            "flyback_s": self.flyback_s,
            "flyback_shape": self.flyback_shape,
            "direction": self.direction,
            "steps": self.steps,
            "predicted_step_m": self.predicted_step_m,
            "predicted_step_band_m": list(self.predicted_step_band_m),
            "predicted_distance_m": self.predicted_distance_m,
            "predicted_distance_band_m": list(self.predicted_distance_band_m),
            "duration_s": self.duration_s,
            "breakaway_accel_m_s2": self.breakaway_accel_m_s2,
            "breakaway_accel_band_m_s2": list(self.breakaway_accel_band_m_s2),
            "margins": dict(self.margins),
            "warnings": list(self.warnings),
        }


def plant_step(
    waveform: Waveform,
    static_accel_m_s2: float,
    kinetic_ratio: float = DEFAULT_KINETIC_RATIO,
    amplifier: AmplifierLimits | None = None,
    stack: StackParameters | None = None,
) -> float:
    """Steady step (m, signed) of ``waveform`` in the full plant model."""
    run = run_waveform(
        Friction(static_accel_m_s2, kinetic_ratio), waveform, PREDICTION_PERIODS, amplifier, stack
    )
    return float(run.steps_m[-1])


def predict_step(
    waveform: Waveform,
    part: Part,
    support: Support = FLAT,
    surface: SurfaceParameters = DEFAULT_SURFACE,
    tau_pa: float | None = None,
    tau_band_pa: float | None = None,
    kinetic_ratio: float = DEFAULT_KINETIC_RATIO,
    amplifier: AmplifierLimits | None = None,
    stack: StackParameters | None = None,
    *,
    tau_adhesion_work_j_m2: float | None = None,
) -> StepPrediction:
    """Step of ``waveform`` for this part (plant model), with the τ and F_k/F_s band.

    τ and w are a pair (:func:`feeder.contact.breakaway.contact`): None = the τ fitted
    with the surface's w."""
    result = contact(
        part,
        support=support,
        surface=surface,
        tau_pa=tau_pa,
        tau_band_pa=tau_band_pa,
        tau_adhesion_work_j_m2=tau_adhesion_work_j_m2,
    )
    return _prediction(waveform, result.breakaway_accel_m_s2, result.breakaway_accel_band_m_s2,
                       kinetic_ratio, amplifier, stack)  # fmt: skip


def _prediction(
    waveform: Waveform,
    a_s: float,
    a_band: tuple[float, float],
    kinetic_ratio: float,
    amplifier: AmplifierLimits | None,
    stack: StackParameters | None,
) -> StepPrediction:
    nominal = plant_step(waveform, a_s, kinetic_ratio, amplifier, stack)
    r_lo, r_hi = kinetic_ratio_band(kinetic_ratio)
    # weakest motion: high a_s and high F_k/F_s; strongest: low a_s and low F_k/F_s
    ends = [
        plant_step(waveform, a_band[1], r_hi, amplifier, stack),
        plant_step(waveform, a_band[0], r_lo, amplifier, stack),
    ]
    return StepPrediction(nominal, (min(*ends, nominal), max(*ends, nominal)))


def flyback_time_s(
    amplitude_v: np.ndarray | float,
    frequency_hz: np.ndarray | float,
    amplifier: AmplifierLimits,
    stack: StackParameters,
) -> tuple[np.ndarray, np.ndarray]:
    """Effective current-limited flyback (s) and swing fraction, bounded by the stack's response."""
    t_f, fraction = amplifier.current_limited_flyback(amplitude_v, frequency_hz, stack.capacitance_f)
    response = 1.0 / (2.0 * stack.resonance_hz) + stack.output_resistance_ohm * stack.capacitance_f
    return np.maximum(t_f, response), fraction


def accelerations(
    amplitude_v: np.ndarray | float,
    frequency_hz: np.ndarray | float,
    amplifier: AmplifierLimits,
    stack: StackParameters,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(flyback accel, ramp accel, stroke, rise, flyback) of a current-limited sawtooth, vectorised."""
    t_f, fraction = flyback_time_s(amplitude_v, frequency_hz, amplifier, stack)
    stroke = stack.gain_m_per_v * np.asarray(amplitude_v) * fraction
    t_r = 1.0 / np.asarray(frequency_hz) - t_f
    with np.errstate(divide="ignore", invalid="ignore"):
        flyback = stroke * (1.0 / t_r + 1.0 / t_f) / t_f
        ramp = 2.0 * stroke / t_r**2
    return flyback, ramp, stroke, t_r, t_f


def plan(
    part: Part,
    support: Support = FLAT,
    surface: SurfaceParameters = DEFAULT_SURFACE,
    tau_pa: float | None = None,
    amplifier: AmplifierLimits | None = None,
    distance_m: float = 0.0,
    *,
    tau_band_pa: float | None = None,
    tau_adhesion_work_j_m2: float | None = None,
    kinetic_ratio: float = DEFAULT_KINETIC_RATIO,
    stack: StackParameters | None = None,
    margin: float = DEFAULT_MARGIN,
    frequency_hz: float | None = None,
) -> Plan:
    """Plan a move of ``distance_m`` (signed: + forward); :class:`InputError` says why not.

    ``tau_pa`` None: the τ fitted with the surface's w; a given τ must come with the w it
    was fitted with (``tau_adhesion_work_j_m2``, default 0), else InputError."""
    amplifier = amplifier or AmplifierLimits()
    stack = stack or StackParameters()
    if not (math.isfinite(distance_m) and distance_m != 0):
        raise InputError("distance_m", f"must be a non-zero finite distance, got {distance_m!r}")
    if not (math.isfinite(margin) and margin >= 1):
        raise InputError("margin", f"must be a number ≥ 1, got {margin!r}")
    result = contact(
        part,
        support=support,
        surface=surface,
        tau_pa=tau_pa,
        tau_band_pa=tau_band_pa,
        tau_adhesion_work_j_m2=tau_adhesion_work_j_m2,
    )
    a_s = result.breakaway_accel_m_s2
    a_lo, a_hi = result.breakaway_accel_band_m_s2

    if frequency_hz is None:  # what the amplifier can be set to (the ANC300: whole hertz)
        grid = np.geomspace(amplifier.min_frequency_hz, amplifier.max_frequency_hz, _FREQUENCY_GRID)
        freqs = np.unique([amplifier.settable_hz(float(f)) for f in grid])
    elif amplifier.min_frequency_hz <= frequency_hz <= amplifier.max_frequency_hz:
        freqs = np.array([amplifier.settable_hz(float(frequency_hz))])
    else:
        raise InputError(
            "frequency_hz",
            f"{frequency_hz:g} Hz is outside the amplifier's "
            f"{amplifier.min_frequency_hz:g}–{amplifier.max_frequency_hz:g} Hz",
        )
    volts = amplifier.max_amplitude_vpp * np.arange(1, _AMPLITUDE_GRID + 1) / _AMPLITUDE_GRID
    v_grid, f_grid = np.meshgrid(volts, freqs)
    fly, ramp, stroke, t_r, t_f = accelerations(v_grid, f_grid, amplifier, stack)
    breaks = (fly >= margin * a_hi) & (t_r >= RISE_PER_FLYBACK * t_f)
    if not breaks.any():
        best = float(np.nanmax(np.where(t_r > 0, fly, np.nan)))
        raise InputError(
            "plan",
            f"no waveform within the amplifier's limits breaks the part loose: the best flyback "
            f"acceleration is {best:.4g} m/s², needed {margin:g} × {a_hi:.4g} m/s² "
            f"(upper end of the breakaway band)",
        )
    ok = breaks & (ramp <= a_lo / margin)
    if not ok.any():
        raise InputError(
            "plan",
            f"the ramp would already make the part slip: every waveform that breaks it loose "
            f"ramps faster than {a_lo:.4g}/{margin:g} m/s² (lower end of the breakaway band)",
        )
    ideal = np.where(ok, linear_flyback_step(stroke, t_r, t_f, kinetic_ratio * a_s), 0.0)
    distance = abs(distance_m)
    best_step = ideal.max(axis=1)
    with np.errstate(divide="ignore"):
        duration = np.where(best_step > 0, np.ceil(distance / best_step) / freqs, np.inf)
    row = int(np.argmin(duration))
    if not math.isfinite(duration[row]):
        raise InputError("plan", "no waveform within the amplifier's limits moves the part")
    freq = float(freqs[row])
    direction = "forward" if distance_m > 0 else "backward"
    feasible = volts[ok[row]]

    def step_at(volts_pp: float) -> float:
        wave = Waveform(frequency_hz=freq, amplitude_vpp=volts_pp, direction=direction)
        return abs(plant_step(wave, a_s, kinetic_ratio, amplifier, stack))

    v_lo, v_hi = float(feasible.min()), float(feasible.max())
    coarse = np.linspace(v_lo, v_hi, 16)
    steps_coarse = np.array([step_at(v) for v in coarse])
    peak = int(np.argmax(steps_coarse))
    if steps_coarse[peak] <= 0:
        raise InputError("plan", "no waveform within the amplifier's limits moves the part")
    steps = max(1, math.ceil(distance / steps_coarse[peak] - 1e-9))
    target = distance / steps
    rising = coarse[: peak + 1]
    values = steps_coarse[: peak + 1]
    above = np.flatnonzero(values >= target)
    k = int(above[0])
    if values[k] == target or k == 0:
        amplitude = float(rising[k])
    else:
        amplitude = float(brentq(lambda v: step_at(v) - target, rising[k - 1], rising[k],
                                 xtol=1e-6, rtol=1e-9))  # fmt: skip
    waveform = Waveform(frequency_hz=freq, amplitude_vpp=amplitude, direction=direction)
    prediction = _prediction(waveform, a_s, (a_lo, a_hi), kinetic_ratio, amplifier, stack)
    fly_c, ramp_c, _, _, t_f_c = (float(x) for x in accelerations(amplitude, freq, amplifier, stack))
    warnings = list(result.warnings)
    if abs(amplitude - v_lo) < 1e-9 and k == 0 and values[0] > target * (1 + 1e-6):
        warnings.append(
            f"the smallest amplitude with the required margins steps {values[0]:.3g} m, more than "
            f"the {target:.3g} m per step the distance needs"
        )
    step = prediction.step_m
    band = prediction.band_m
    return Plan(
        distance_m=distance_m,
        frequency_hz=freq,
        amplitude_vpp=amplitude,
        flyback_s=t_f_c,
        flyback_shape="current-limited",
        direction=direction,
        steps=steps,
        predicted_step_m=step,
        predicted_step_band_m=band,
        predicted_distance_m=steps * step,
        predicted_distance_band_m=(steps * band[0], steps * band[1]),
        duration_s=steps / freq,
        breakaway_accel_m_s2=a_s,
        breakaway_accel_band_m_s2=(a_lo, a_hi),
        margins={
            "required": margin,
            "flyback_accel_m_s2": fly_c,
            "flyback_margin": fly_c / a_hi,
            "ramp_accel_m_s2": ramp_c,
            "ramp_margin": a_lo / ramp_c,
        },
        warnings=tuple(warnings),
    )
