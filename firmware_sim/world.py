"""The physical world behind the amplifier: the plant and a camera, with "true" parameters.

The plant is :class:`feeder.plant.plant.Plant` (amplifier output stage → stack
+ plate → part stick-slip) fed with the DAC stream of one axis.  Its
parameters are the world's own, not the host's nominal ones (DESIGN §6): τ is
drawn within the paper's band 22.18 ± 3.15 GPa from the seed (or set, or
offset from the nominal value), and a_s scatters from stick to stick.

The camera exposes at ``rate_hz`` on the world's clock, reads the part's
position at that sample plus Gaussian noise, and releases the frame
``latency_s`` later as one JSON line ``{"seq", "time_s", "position_m"}``.
"""

from __future__ import annotations

import heapq
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from feeder.contact.breakaway import DEFAULT_TAU_BAND_PA, DEFAULT_TAU_PA, contact
from feeder.parts import Part, Support
from feeder.plant.plant import Plant
from feeder.plant.stack import StackParameters
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO, Friction
from firmware_sim.clock import VirtualClock
from firmware_sim.firmware import PHASE_BITS, Axis, Firmware, FirmwareConfig

WARMUP_STEPS = 2
MEASURED_STEPS = 3
SCATTER_STEPS = 20


@dataclass(frozen=True)
class TrueStep:
    """The plant's true steady-state step up and down (m, signed) and its relative
    single-step spread (1σ / mean) from the per-stick scatter of the friction."""

    up_m: float
    down_m: float
    scatter: float


@dataclass(frozen=True)
class CameraConfig:
    """Frame rate (Hz), position noise (m, 1σ) and latency exposure → frame out (s)."""

    rate_hz: float = 100.0
    noise_m: float = 50e-9
    latency_s: float = 0.010


@dataclass(frozen=True)
class WorldConfig:
    """The true world.

    tau_pa: true interfacial shear strength; ``None`` draws it uniformly within
        DEFAULT_TAU_PA ± DEFAULT_TAU_BAND_PA from ``seed``, unless ``tau_offset``
        (relative, 0.15 = 15 % above nominal) is given.
    scatter: per-stick relative scatter of a_s (step-to-step spread).
    plant_axis: the amplifier axis the stack is wired to.
    """

    part: str = "300x300x50"
    support: str = "flat"
    tau_pa: float | None = None
    tau_offset: float | None = None
    kinetic_ratio: float = DEFAULT_KINETIC_RATIO
    scatter: float = 0.02
    seed: int = 0
    plant_axis: int = 1
    stack: StackParameters = field(default_factory=StackParameters)
    camera: CameraConfig = field(default_factory=CameraConfig)

    def true_tau_pa(self) -> float:
        if self.tau_pa is not None:
            return self.tau_pa
        if self.tau_offset is not None:
            return DEFAULT_TAU_PA * (1.0 + self.tau_offset)
        rng = np.random.default_rng(self.seed)
        return float(rng.uniform(DEFAULT_TAU_PA - DEFAULT_TAU_BAND_PA,
                                 DEFAULT_TAU_PA + DEFAULT_TAU_BAND_PA))


class World:
    """Plant + camera attached to a firmware's DAC stream (see :meth:`attach`)."""

    def __init__(self, config: WorldConfig, firmware_config: FirmwareConfig,
                 publish: Callable[[bytes], None] | None = None) -> None:
        self.config = config
        self.firmware_config = firmware_config
        self.tau_pa = config.true_tau_pa()
        result = contact(Part.parse(config.part), Support.parse(config.support), tau_pa=self.tau_pa)
        self.friction = Friction(result.breakaway_accel_m_s2, config.kinetic_ratio)
        self.plant = self._plant(config.scatter, config.seed)
        self.position_m = self.plant.part_position_m
        self.time_s = 0.0
        self.publish = publish
        self._rng = np.random.default_rng(config.seed + 1)
        self._next_frame = 0
        self._pending: list[tuple[float, int, float, float]] = []

    def _plant(self, scatter: float, seed: int | None) -> Plant:
        return Plant(self.friction, amplifier=self.firmware_config.amplifier,
                     stack=self.config.stack, sample_rate_hz=self.firmware_config.sample_rate_hz,
                     scatter=scatter, seed=seed)

    def attach(self, firmware: Firmware) -> None:
        """Feed the plant axis' DAC stream to the plant and release camera frames each tick."""
        firmware.add_sink(self._on_dac)
        firmware.add_tick_listener(self._on_tick)

    def _on_dac(self, axis: int, first: int, volts: np.ndarray) -> None:
        if axis != self.config.plant_axis:
            return
        positions = self.plant.advance(volts)
        self.position_m = float(positions[-1])
        camera = self.config.camera
        rate = self.firmware_config.sample_rate_hz
        while True:
            sample = round(self._next_frame * rate / camera.rate_hz)
            if sample >= first + volts.size:
                break
            if sample >= first:
                t = sample / rate
                noisy = float(positions[sample - first]) + camera.noise_m * float(
                    self._rng.standard_normal())
                heapq.heappush(self._pending, (t + camera.latency_s, self._next_frame, t, noisy))
            self._next_frame += 1

    def _on_tick(self, now_s: float) -> None:
        self.time_s = now_s
        while self._pending and self._pending[0][0] <= now_s + 1e-9:
            _, seq, t, position = heapq.heappop(self._pending)
            if self.publish is not None:
                line = json.dumps({"seq": seq, "time_s": t, "position_m": position})
                self.publish(line.encode() + b"\n")

    def part_poses(self) -> list[tuple[float, float, float]]:
        """The parts' true poses (x, y, ψ) in the plate frame (m, m, rad): the plant is 1-D
        for now, so one part at (position, 0, 0)."""
        return [(self.position_m, 0.0, 0.0)]

    def true_step(self, axis: Axis) -> TrueStep:
        """The plant's true step for ``axis``' current settings, measured, not predicted.

        A fresh firmware with the axis' flyback (or patterns), amplitude, offset,
        frequency and mode drives a fresh copy of the true plant.  The step is
        the part's displacement between the same phase (mid-period) of two
        periods of one burst, after two warm-up periods, per period: without
        scatter for the mean, with the world's scatter for the spread.
        """
        up = self._period_steps(axis, 1, MEASURED_STEPS, scatter=0.0)
        down = self._period_steps(axis, -1, MEASURED_STEPS, scatter=0.0)
        spread = 0.0
        if self.config.scatter > 0:
            steps = self._period_steps(axis, 1, SCATTER_STEPS, scatter=self.config.scatter)
            spread = float(np.std(steps) / abs(np.mean(steps))) if np.mean(steps) else 0.0
        return TrueStep(float(np.mean(up)), float(np.mean(down)), spread)

    def _period_steps(self, axis: Axis, sign: int, count: int, scatter: float) -> np.ndarray:
        """Per-period displacements (m) of ``count`` periods of a burst after the warm-up."""
        status = axis.status()
        config = FirmwareConfig(axes=1, tick_hz=self.firmware_config.tick_hz,
                                sample_rate_hz=self.firmware_config.sample_rate_hz,
                                amplifier=self.firmware_config.amplifier,
                                load_capacitance_f=self.firmware_config.load_capacitance_f,
                                watchdog_s=math.inf)
        firmware = Firmware(config)
        probe = firmware.axis(1)
        probe.set_frequency(status.frequency_hz)
        if status.flyback_shape == "custom":
            probe.set_pattern(True, axis.pattern(True))
            probe.set_pattern(False, axis.pattern(False))
        else:
            probe.set_flyback(status.flyback_shape, status.flyback_s)
        probe.set_amplitude(status.amplitude_v)
        probe.set_offset(status.offset_v)
        probe.set_mode(status.mode if status.mode in ("stp+", "stp-") else "stp")
        plant = self._plant(scatter, self.config.seed + 2)
        trace: list[np.ndarray] = []
        firmware.add_sink(lambda _axis, _first, volts: trace.append(plant.advance(volts)))
        increment = round(status.frequency_hz * (1 << PHASE_BITS) / config.sample_rate_hz)
        period = (1 << PHASE_BITS) / increment  # samples per DDS period
        steps = WARMUP_STEPS + count + 1
        probe.step(sign * steps)
        firmware.run(VirtualClock(), max_ticks=math.ceil(steps * period
                                                          / config.samples_per_tick) + 2)
        x = np.concatenate(trace)
        at = [round((k + 0.5) * period) for k in range(WARMUP_STEPS, steps)]
        return np.diff(x[at])

    def describe(self) -> dict[str, object]:
        """The true parameters, for the ready line."""
        return {"tau_pa": self.tau_pa,
                "static_accel_m_s2": self.friction.static_accel_m_s2,
                "kinetic_ratio": self.friction.kinetic_ratio,
                "scatter": self.config.scatter,
                "part": self.config.part, "support": self.config.support,
                "plant_axis": self.config.plant_axis,
                "camera": {"rate_hz": self.config.camera.rate_hz,
                           "noise_m": self.config.camera.noise_m,
                           "latency_s": self.config.camera.latency_s}}
