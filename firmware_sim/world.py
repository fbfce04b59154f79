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
from firmware_sim.firmware import Axis, Firmware, FirmwareConfig

SETTLE_S = 0.005
WARMUP_STEPS = 2
MEASURED_STEPS = 3


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
        while self._pending and self._pending[0][0] <= now_s:
            _, seq, t, position = heapq.heappop(self._pending)
            if self.publish is not None:
                line = json.dumps({"seq": seq, "time_s": t, "position_m": position})
                self.publish(line.encode() + b"\n")

    def true_steps_m(self, axis: Axis) -> tuple[float, float]:
        """The plant's mean step up and down (m, signed) for ``axis``' current settings.

        Measured, not predicted: a fresh firmware with the axis' patterns,
        amplitude, offset, frequency and mode drives a fresh copy of the true
        plant without scatter; after two warm-up steps, the mean of three.
        """
        status = axis.status()
        config = FirmwareConfig(axes=1, tick_hz=self.firmware_config.tick_hz,
                                sample_rate_hz=self.firmware_config.sample_rate_hz,
                                amplifier=self.firmware_config.amplifier,
                                load_capacitance_f=self.firmware_config.load_capacitance_f,
                                watchdog_s=math.inf)
        firmware = Firmware(config)
        probe = firmware.axis(1)
        probe.set_pattern(True, axis.pattern(True))
        probe.set_pattern(False, axis.pattern(False))
        probe.set_frequency(status.frequency_hz)
        probe.set_amplitude(status.amplitude_v)
        probe.set_offset(status.offset_v)
        probe.set_mode(status.mode if status.mode in ("stp+", "stp-") else "stp")
        plant = self._plant(0.0, None)
        latest = [plant.part_position_m]

        def feed(_axis: int, _first: int, volts: np.ndarray) -> None:
            latest[0] = float(plant.advance(volts)[-1])

        firmware.add_sink(feed)
        clock = VirtualClock()
        settle_ticks = math.ceil(SETTLE_S * config.tick_hz)
        burst_ticks = math.ceil(config.tick_hz / status.frequency_hz)

        def burst(count: int) -> float:
            probe.step(count)
            firmware.run(clock, max_ticks=abs(count) * burst_ticks + settle_ticks)
            return latest[0]

        steps = []
        for sign in (1, -1):
            burst(sign * WARMUP_STEPS)
            start = latest[0]
            end = burst(sign * MEASURED_STEPS)
            steps.append((end - start) / MEASURED_STEPS)
        return steps[0], steps[1]

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
