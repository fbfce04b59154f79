"""The physical world behind the amplifier: the plant and a camera, with "true" parameters.

The plant is :class:`feeder.plant.plant.Plant` (amplifier output stage → stack
+ plate → part stick-slip) fed with the DAC stream of one axis.  Its
parameters are the world's own, not the host's nominal ones (DESIGN §6): τ is
drawn within the paper's band 22.18 ± 3.15 GPa from the seed (or set, or
offset from the nominal value), and a_s scatters from stick to stick.

With ``plant="planar"`` the plant is :class:`feeder.plant.planar_plant.PlanarPlant`
instead: axes 1, 2, 3 drive the plate's x, y and θ (one amplifier and stack
model each), several parts sit at their poses, and the camera sees each
part's pose (x, y, ψ) in the lab frame (the plate frame at the end of each
period, when the plate is back at its start).  The planar plant has no
step-to-step scatter.

The camera exposes at ``rate_hz`` on the world's clock, reads the part's
position at that sample plus Gaussian noise, and releases the frame
``latency_s`` later as one JSON line ``{"seq", "time_s", "position_m"}``
(planar: plus ``"poses"``, [[x_m, y_m, psi_rad], ...] per part, noise on x
and y; ``position_m`` is the first part's x).
"""

from __future__ import annotations

import heapq
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from feeder.contact.breakaway import DEFAULT_TAU_BAND_PA, DEFAULT_TAU_PA, contact
from feeder.errors import InputError
from feeder.parts import Part, Support
from feeder.plant.planar import PlanarPart, Pose
from feeder.plant.planar_plant import DEFAULT_LEVER_ARM_M, PlanarPlant
from feeder.plant.plant import Plant
from feeder.plant.stack import StackParameters
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO, Friction
from firmware_sim.axis import PHASE_BITS, Axis
from firmware_sim.clock import VirtualClock
from firmware_sim.firmware import Firmware, FirmwareConfig

WARMUP_STEPS = 2
MEASURED_STEPS = 3
SCATTER_STEPS = 20
PLANTS = ("line", "planar")
PLANAR_AXES = 3


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
    plant_axis: the amplifier axis the stack is wired to (line plant).
    plant: ``line`` (one axis, the default) or ``planar`` (axes 1–3 = x, y, θ).
    poses: the parts' poses (planar), plate frame (m, m, rad).
    lever_arm_m: radius about O at which the θ stack drives the plate (planar).
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
    plant: str = "line"
    poses: tuple[Pose, ...] = ((0.0, 0.0, 0.0),)
    lever_arm_m: float = DEFAULT_LEVER_ARM_M

    def true_tau_pa(self) -> float:
        if self.tau_pa is not None:
            return self.tau_pa
        if self.tau_offset is not None:
            return DEFAULT_TAU_PA * (1.0 + self.tau_offset)
        rng = np.random.default_rng(self.seed)
        return float(rng.uniform(DEFAULT_TAU_PA - DEFAULT_TAU_BAND_PA, DEFAULT_TAU_PA + DEFAULT_TAU_BAND_PA))


class World:
    """Plant + camera attached to a firmware's DAC stream (see :meth:`attach`)."""

    def __init__(
        self,
        config: WorldConfig,
        firmware_config: FirmwareConfig,
        publish: Callable[[bytes], None] | None = None,
    ) -> None:
        if config.plant not in PLANTS:
            raise InputError("--plant", f"expected one of {', '.join(PLANTS)}, got {config.plant!r}")
        self.config = config
        self.firmware_config = firmware_config
        self.tau_pa = config.true_tau_pa()
        result = contact(Part.parse(config.part), Support.parse(config.support), tau_pa=self.tau_pa)
        self.friction = Friction(result.breakaway_accel_m_s2, config.kinetic_ratio)
        self.plant = self._plant(config.scatter, config.seed)
        self.planar = self._planar_plant(Part.parse(config.part)) if config.plant == "planar" else None
        self._chunks: dict[int, np.ndarray] = {}
        self.position_m = self.plant.part_position_m if self.planar is None else self.planar.lab_poses()[0][0]
        self.time_s = 0.0
        self.publish = publish
        self._rng = np.random.default_rng(config.seed + 1)
        self._next_frame = 0
        self._pending: list[tuple[float, int, dict[str, object]]] = []

    def _plant(self, scatter: float, seed: int | None) -> Plant:
        return Plant(
            self.friction,
            amplifier=self.firmware_config.amplifier,
            stack=self.config.stack,
            sample_rate_hz=self.firmware_config.sample_rate_hz,
            scatter=scatter,
            seed=seed,
        )

    def _planar_plant(self, part: Part) -> PlanarPlant:
        if self.firmware_config.axes < PLANAR_AXES:
            raise InputError("--axes", f"the planar plant needs axes 1–{PLANAR_AXES}, "
                             f"got {self.firmware_config.axes}")  # fmt: skip
        parts = [PlanarPart.from_part(part, self.friction, pose) for pose in self.config.poses]

        def build() -> PlanarPlant:
            return PlanarPlant(parts, amplifier=self.firmware_config.amplifier, stack=self.config.stack,
                               sample_rate_hz=self.firmware_config.sample_rate_hz,
                               lever_arm_m=self.config.lever_arm_m)  # fmt: skip

        # a throwaway copy takes one sample: numba compiles (or loads, ~50 ms) the plant's kernels
        # now, before the ready line, not in the first tick that drives the plate
        build().advance(np.zeros((3, 1)))
        return build()

    def attach(self, firmware: Firmware) -> None:
        """Feed the plant axis' DAC stream to the plant and release camera frames each tick."""
        firmware.add_sink(self._on_dac)
        firmware.add_tick_listener(self._on_tick)

    def _on_dac(self, axis: int, first: int, volts: np.ndarray) -> None:
        if self.planar is not None:
            self._on_planar_dac(axis, first, volts)
            return
        if axis != self.config.plant_axis:
            return
        positions = self.plant.advance(volts)
        self.position_m = float(positions[-1])
        self._expose(first, positions)

    def _on_planar_dac(self, axis: int, first: int, volts: np.ndarray) -> None:
        """Collect the tick's chunks of axes 1–3, then run the planar plant on them."""
        if axis > PLANAR_AXES:
            return
        self._chunks[axis] = volts
        if len(self._chunks) < PLANAR_AXES:
            return
        command = np.stack([self._chunks[a] for a in range(1, PLANAR_AXES + 1)])
        self._chunks.clear()
        assert self.planar is not None
        poses = self.planar.advance(command)  # (parts, n, 3), lab frame
        self.position_m = float(poses[0, -1, 0])
        self._expose(first, poses[0, :, 0], poses)

    def _expose(self, first: int, positions: np.ndarray, poses: np.ndarray | None = None) -> None:
        """Queue the camera frames whose exposure falls in this chunk (samples first…)."""
        camera = self.config.camera
        rate = self.firmware_config.sample_rate_hz
        while True:
            sample = round(self._next_frame * rate / camera.rate_hz)
            if sample >= first + positions.size:
                break
            if sample >= first:
                t = sample / rate
                frame: dict[str, object] = {"seq": self._next_frame, "time_s": t}
                if poses is None:
                    frame["position_m"] = float(positions[sample - first]) + camera.noise_m * float(
                        self._rng.standard_normal()
                    )
                else:
                    seen = poses[:, sample - first].copy()
                    seen[:, :2] += camera.noise_m * self._rng.standard_normal((seen.shape[0], 2))
                    frame["position_m"] = float(seen[0, 0])
                    frame["poses"] = seen.tolist()
                heapq.heappush(self._pending, (t + camera.latency_s, self._next_frame, frame))
            self._next_frame += 1

    def _on_tick(self, now_s: float) -> None:
        self.time_s = now_s
        while self._pending and self._pending[0][0] <= now_s + 1e-9:
            frame = heapq.heappop(self._pending)[2]
            if self.publish is not None:
                self.publish(json.dumps(frame).encode() + b"\n")

    def part_poses(self) -> list[tuple[float, float, float]]:
        """The parts' true poses (x, y, ψ) as the camera sees them (lab frame; m, m, rad):
        the line plant has one part at (position, 0, 0)."""
        if self.planar is not None:
            return [(float(x), float(y), float(psi)) for x, y, psi in self.planar.lab_poses()]
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
        config = FirmwareConfig(
            axes=1,
            tick_hz=self.firmware_config.tick_hz,
            sample_rate_hz=self.firmware_config.sample_rate_hz,
            amplifier=self.firmware_config.amplifier,
            load_capacitance_f=self.firmware_config.load_capacitance_f,
            watchdog_s=math.inf,
        )
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
        firmware.run(VirtualClock(), max_ticks=math.ceil(steps * period / config.samples_per_tick) + 2)
        x = np.concatenate(trace)
        at = [round((k + 0.5) * period) for k in range(WARMUP_STEPS, steps)]
        return np.diff(x[at])

    def describe(self) -> dict[str, object]:
        """The true parameters, for the ready line."""
        return {
            "tau_pa": self.tau_pa,
            "static_accel_m_s2": self.friction.static_accel_m_s2,
            "kinetic_ratio": self.friction.kinetic_ratio,
            "scatter": self.config.scatter,
            "part": self.config.part,
            "support": self.config.support,
            "plant_axis": self.config.plant_axis,
            "plant": self.config.plant,
            **(
                {"poses": [list(p) for p in self.config.poses], "lever_arm_m": self.config.lever_arm_m}
                if self.planar is not None
                else {}
            ),
            "camera": {
                "rate_hz": self.config.camera.rate_hz,
                "noise_m": self.config.camera.noise_m,
                "latency_s": self.config.camera.latency_s,
            },
        }
