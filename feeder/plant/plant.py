"""The whole plant: DAC command → amplifier limits → stack + plate → part stick-slip.

:class:`Plant` streams: each :meth:`Plant.advance` call takes the next chunk of
command-voltage samples (e.g. 100 samples per 1 ms tick at 100 kS/s) and
returns the part's position at each sample, with all state carried over.
Between samples the plate's acceleration is held at (v_k − v_{k−1})·rate, the
plate velocities coming from the discretised stack model; the stick-slip on
that motion is solved exactly (:mod:`feeder.plant.stick_slip`).

``oversample`` N > 1 runs the stack and the contact N times per DAC sample, on
the amplifier's output voltage interpolated linearly between samples (exact: a
slope-limited output is piecewise linear), so that the stack's ringing is
resolved between the DAC's samples.  At the default 30 kHz resonance and
100 kS/s (3.3 samples per ringing period) the paper's waveform steps 2.1 %
further at N = 1 than converged (N ≥ 10); docs/plant.md, *Discretisation*.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feeder.contact.breakaway import DEFAULT_TAU_PA, contact
from feeder.errors import InputError
from feeder.parts import FLAT, Part, Support
from feeder.plant import kernels
from feeder.plant.amplifier import AmplifierLimits, OutputStage
from feeder.plant.stack import StackFilter, StackParameters
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO, Friction, StickSlip
from feeder.surface.parameters import DEFAULT_SURFACE, SurfaceParameters
from feeder.waveform import Waveform

DEFAULT_SAMPLE_RATE_HZ = 100e3
MAX_OVERSAMPLE = 64
MAX_PERIODS = 10**6
"""The most periods one simulation runs (``feeder simulate --periods``, a sweep's ``periods``)."""
BYTES_PER_SAMPLE = 64
"""Memory a simulation holds per sample (the plant's traces and temporaries, 8 float64; the ideal
plate's per interval of a row: both measured ~45), for the memory budget."""


class Plant:
    """Amplifier + stack + plate + part, streaming at ``sample_rate_hz``.

    friction: the part's a_s and F_k/F_s; amplifier, stack: model parameters;
    scatter, seed: per-stick relative scatter of a_s (see
    :class:`~feeder.plant.stick_slip.StickSlip`); initial_v: output voltage at
    rest at the start (the part sits on the plate at x = g·initial_v);
    oversample: stack and contact steps per DAC sample (module docstring).
    """

    def __init__(
        self,
        friction: Friction,
        amplifier: AmplifierLimits | None = None,
        stack: StackParameters | None = None,
        sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
        scatter: float = 0.0,
        seed: int | None = None,
        initial_v: float = 0.0,
        oversample: int = 1,
    ) -> None:
        whole = isinstance(oversample, int) and not isinstance(oversample, bool)
        if not whole or not 1 <= oversample <= MAX_OVERSAMPLE:
            raise InputError("oversample", f"must be an integer in [1, {MAX_OVERSAMPLE}], got {oversample!r}")
        self.amplifier = amplifier or AmplifierLimits()
        self.stack = stack or StackParameters()
        self.sample_rate_hz = float(sample_rate_hz)
        self.oversample = oversample
        self.output = OutputStage(self.amplifier, self.stack.capacitance_f, sample_rate_hz, initial_v)
        self.mechanics = StackFilter(self.stack, sample_rate_hz * oversample, self.output.voltage_v)
        self.contact = StickSlip(friction, scatter=scatter, seed=seed)
        self.plate_position_m = self.stack.gain_m_per_v * self.output.voltage_v
        self.plate_velocity_m_s = 0.0
        self._coefficients: np.ndarray | None = None  # of the compiled path

    @classmethod
    def from_contact(
        cls,
        part: Part,
        support: Support = FLAT,
        surface: SurfaceParameters = DEFAULT_SURFACE,
        tau_pa: float = DEFAULT_TAU_PA,
        kinetic_ratio: float = DEFAULT_KINETIC_RATIO,
        **kwargs: object,
    ) -> Plant:
        """A plant whose a_s is the contact model's breakaway acceleration τ·A_r/m."""
        result = contact(part, support=support, surface=surface, tau_pa=tau_pa)
        friction = Friction(result.breakaway_accel_m_s2, kinetic_ratio)
        return cls(friction, **kwargs)  # type: ignore[arg-type]

    @property
    def part_position_m(self) -> float:
        return self.plate_position_m + self.contact.relative_position_m

    @property
    def output_voltage_v(self) -> float:
        return self.output.voltage_v

    @property
    def elapsed_s(self) -> float:
        return self.contact.elapsed_s

    @property
    def slip_time_s(self) -> float:
        return self.contact.slip_time_s

    def advance(self, command_volts: np.ndarray) -> np.ndarray:
        """Run the next command samples (V); returns the part position (m) at each sample."""
        return self.advance_traces(command_volts)[0]

    def advance_traces(self, command_volts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Like :meth:`advance`; returns (part position, plate position) in m at each sample."""
        command = np.asarray(command_volts, dtype=float)
        if command.size == 0:
            return np.zeros(0), np.zeros(0)
        n = self.oversample
        if n > 1:  # the output stage at the DAC's rate, then its piecewise-linear voltage N times finer
            before = self.output.voltage_v
            voltage = self.output.advance(command)
            previous = np.concatenate([[before], voltage[:-1]])
            fraction = np.arange(1, n + 1) / n
            command = (previous[:, None] + (voltage - previous)[:, None] * fraction).ravel()
        if kernels.enabled() and self.mechanics.order == kernels.FILTER_ORDER:
            part, plate = self._advance_compiled(command)
        else:
            part, plate = self._advance_stepped(command)
        return (part, plate) if n == 1 else (part[n - 1 :: n], plate[n - 1 :: n])

    def _advance_stepped(self, command: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`advance_traces` in numpy: the whole chunk's filters, then the contact."""
        voltage = self.output.advance(command) if self.oversample == 1 else command
        rate = self.sample_rate_hz * self.oversample
        position, velocity = self.mechanics.advance(voltage)
        accel = np.empty(velocity.size)
        accel[0] = velocity[0] - self.plate_velocity_m_s
        np.subtract(velocity[1:], velocity[:-1], out=accel[1:])
        accel *= rate
        relative = self.contact.advance(accel, 1.0 / rate)
        self.plate_position_m = float(position[-1])
        self.plate_velocity_m_s = float(velocity[-1])
        return position + relative, position

    def _advance_compiled(self, command: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`advance_traces` in one compiled loop (:func:`feeder.plant.kernels.plant_run`); with
        ``oversample`` > 1 ``command`` is the output voltage already (the loop's stage passes it)."""
        if self._coefficients is None:
            limits = self.output.limits
            stage = ([limits.v_min_v, limits.v_max_v, self.output.max_step_v] if self.oversample == 1
                     else [-math.inf, math.inf, math.inf])  # fmt: skip
            self._coefficients = np.concatenate([stage, self.mechanics.coefficients()])
        n = command.size
        part, plate = np.empty(n), np.empty(n)
        contact, coef = self.contact, self._coefficients
        friction = contact.friction
        z = self.mechanics.states
        rate = self.sample_rate_hz * self.oversample
        motion = np.array([self.output.voltage_v, self.plate_velocity_m_s, rate])
        contact.run_kernel(lambda st, start: kernels.plant_run(
            command, coef, z, motion, st, friction.static_accel_m_s2, friction.kinetic_ratio,
            contact.scatter, contact.normals, part, plate, start), n)  # fmt: skip
        self.mechanics.states = z
        contact.elapsed_s += n / rate
        self.output.voltage_v = float(motion[0])
        self.plate_velocity_m_s = float(motion[1])
        self.plate_position_m = float(plate[-1])
        return part, plate


@dataclass(frozen=True)
class WaveformRun:
    """Result of :func:`run_waveform`: per-period steps (m) and the traces."""

    steps_m: np.ndarray
    net_displacement_m: float
    slip_fraction: float
    time_s: np.ndarray
    part_position_m: np.ndarray
    plate_position_m: np.ndarray


def run_waveform(
    friction: Friction,
    waveform: Waveform,
    periods: int,
    amplifier: AmplifierLimits | None = None,
    stack: StackParameters | None = None,
    sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
    scatter: float = 0.0,
    seed: int | None = None,
    oversample: int = 1,
) -> WaveformRun:
    """Drive a fresh plant, at rest at the bottom of the sawtooth, for ``periods`` steps.

    The command is sampled like a DDS (phase = sample index / samples per
    period), at the rate nearest ``sample_rate_hz`` that holds a whole number
    of samples per period (the frequency stays exact).  Steps are measured
    between the last samples before consecutive flybacks, where the part rides
    the rise stuck to the plate: the first rise is a lead-in, so the run is
    ``periods`` periods plus one rise long.  oversample: :class:`Plant`'s.
    """
    per = round(sample_rate_hz / waveform.frequency_hz)
    if per < 4:
        raise InputError("sample_rate_hz", "needs at least 4 samples per period")
    bottom = waveform.offset_v + (0.0 if waveform.sign > 0 else waveform.amplitude_vpp)
    rate = per * waveform.frequency_hz
    plant = Plant(friction, amplifier, stack, rate, scatter, seed, initial_v=bottom, oversample=oversample)
    top = math.ceil((1.0 - waveform.command_flyback_s * waveform.frequency_hz) * per - 1e-9) - 1
    count = top + 1 + periods * per
    index = np.arange(1, count + 1)
    part, plate = plant.advance_traces(waveform.voltage_at_phase((index % per) / per))
    tops = part[top::per]
    return WaveformRun(
        steps_m=np.diff(tops),
        net_displacement_m=float(tops[-1] - tops[0]),
        slip_fraction=plant.slip_time_s / plant.elapsed_s,
        time_s=index / rate,
        part_position_m=part,
        plate_position_m=plate,
    )
