"""In-process test doubles for the daemon's unit tests: a part that moves N × step.

``FakeWorld`` is the part on its plate in real time: a burst of ``n`` steps at
``f`` Hz moves it one step every ``1/f`` s, by the world's true step for the
applied amplitude and direction (with seeded Gaussian scatter).  The fake
amplifier and the fake sensor are views of it.  Not product code: the product
talks to firmware_sim through the real drivers.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from feeder.drivers.amplifier import (
    Amplifier,
    AmplifierError,
    AmplifierLinkLost,
    AmplifierStatus,
    DriveSettings,
)
from feeder.drivers.sensor import PositionSample, PositionSensor, SensorLost


class FakeWorld:
    """True step (m) per (amplitude V, +1/−1 direction); position in m."""

    def __init__(
        self,
        true_steps: dict[tuple[float, int], float],
        scatter: float = 0.0,
        noise_m: float = 0.0,
        seed: int = 1,
        position_m: float = 0.0,
    ) -> None:
        self.true_steps = true_steps
        self.scatter = scatter
        self.noise_m = noise_m
        self.rng = np.random.default_rng(seed)
        self.lock = threading.Lock()
        self.base_m = position_m
        self.settings: DriveSettings | None = None
        self.burst_start = 0.0
        self.burst_steps = 0
        self.burst_sign = 0
        self.burst_increments: np.ndarray = np.zeros(0)
        self.stuck = False
        self.total_steps = 0
        # a backward burst leaves the output at its amplitude (a forward one at 0 V); a new
        # amplitude then moves the plate, and the stuck part with it, by gain × ΔV
        self.stack_gain_m_per_v = 0.0
        self.rest_v = 0.0

    def set_amplitude(self, settings: DriveSettings) -> None:
        with self.lock:
            if self.rest_v > 0:
                self.base_m += self.stack_gain_m_per_v * (settings.amplitude_v - self.rest_v)
                self.rest_v = settings.amplitude_v
            self.settings = settings

    def _done_steps(self, now: float) -> int:
        if self.burst_steps == 0 or self.settings is None:
            return 0
        return min(self.burst_steps, int((now - self.burst_start) * self.settings.frequency_hz))

    def position(self, now: float) -> float:
        with self.lock:
            done = self._done_steps(now)
            return self.base_m + self.burst_sign * float(self.burst_increments[:done].sum())

    def moving(self, now: float) -> bool:
        with self.lock:
            return self._done_steps(now) < self.burst_steps

    def start_burst(self, count: int, now: float) -> None:
        with self.lock:
            done = self._done_steps(now)
            self.base_m += self.burst_sign * float(self.burst_increments[:done].sum())
            assert self.settings is not None
            sign = 1 if count > 0 else -1
            step = 0.0 if self.stuck else self.true_steps[(self.settings.amplitude_v, sign)]
            n = abs(count)
            self.burst_increments = step * (1 + self.scatter * self.rng.standard_normal(n))
            self.burst_start, self.burst_steps, self.burst_sign = now, n, sign
            self.total_steps += n
            self.rest_v = self.settings.amplitude_v if sign < 0 else 0.0

    def stop(self, now: float) -> None:
        with self.lock:
            done = self._done_steps(now)
            self.base_m += self.burst_sign * float(self.burst_increments[:done].sum())
            self.burst_steps = 0
            self.burst_increments = np.zeros(0)


class FakeAmplifier(Amplifier):
    def __init__(self, world: FakeWorld) -> None:
        self.world = world
        self.link_up = True
        self.grounded = True
        self.faults: tuple[str, ...] = ()  # latched, as firmware_sim's fault word
        self.calls: list[str] = []

    def _check(self, name: str) -> None:
        self.calls.append(name)
        if not self.link_up:
            raise AmplifierLinkLost("fake link down")

    def apply(self, settings: DriveSettings) -> None:
        self._check("apply")
        self.world.set_amplitude(settings)

    def step(self, count: int) -> None:
        self._check("step")
        assert count != 0
        if self.grounded or self.faults:
            raise AmplifierError("Axis in wrong mode")
        self.world.start_burst(count, time.monotonic())

    def run_continuous(self, forward: bool) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        self._check("stop")
        self.world.stop(time.monotonic())

    def wait(self, timeout_s: float) -> bool:
        self._check("wait")
        end = time.monotonic() + timeout_s
        while self.world.moving(time.monotonic()):
            if time.monotonic() > end:
                return False
            time.sleep(0.001)
        return True

    def ground(self) -> None:
        self._check("ground")
        self.grounded = True

    def enable(self) -> None:
        self._check("enable")
        if self.faults:
            raise AmplifierError("Axis in wrong mode")
        self.grounded = False

    def clear_faults(self) -> None:
        self._check("clear_faults")
        self.faults = ()

    def status(self) -> AmplifierStatus:
        self._check("status")
        s = self.world.settings
        return AmplifierStatus(
            mode="gnd" if self.grounded else "stp",
            frequency_hz=s.frequency_hz if s else 0.0,
            amplitude_v=s.amplitude_v if s else 0.0,
            step_counter=self.world.total_steps,
            moving=self.world.moving(time.monotonic()),
            fault_word=len(self.faults),
            faults=self.faults,
        )

    def close(self) -> None:
        self.calls.append("close")


class FakeSensor(PositionSensor):
    """Frames at ``rate_hz`` of the world's position plus Gaussian noise."""

    def __init__(self, world: FakeWorld, rate_hz: float = 200.0) -> None:
        self.world = world
        self.period = 1.0 / rate_hz
        self.sequence = 0
        self.next_frame = time.monotonic()
        self.lost = False
        self.paused = False
        self.closed = False

    def read(self, timeout_s: float = 1.0) -> PositionSample:
        end = time.monotonic() + timeout_s
        while self.paused and not self.lost and not self.closed:
            if time.monotonic() > end:
                raise SensorLost("fake sensor: no frame")
            time.sleep(0.005)
        if self.lost or self.closed:
            raise SensorLost("fake sensor lost")
        delay = self.next_frame - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        self.next_frame = max(self.next_frame + self.period, time.monotonic())
        now = time.monotonic()
        self.sequence += 1
        with self.world.lock:
            noise = self.world.noise_m * float(self.world.rng.standard_normal())
        return PositionSample(now, self.world.position(now) + noise, self.sequence)

    def close(self) -> None:
        self.closed = True


def test_fake_world_moves_n_times_the_true_step() -> None:
    world = FakeWorld({(100.0, 1): 3e-6, (100.0, -1): 2e-6})
    amp = FakeAmplifier(world)
    amp.apply(DriveSettings(frequency_hz=1000.0, amplitude_v=100.0))
    amp.enable()
    amp.step(7)
    assert amp.wait(2.0)
    assert math.isclose(world.position(time.monotonic()), 21e-6, rel_tol=1e-12)
    amp.step(-4)
    assert amp.wait(2.0)
    assert world.position(time.monotonic()) == pytest.approx(13e-6, rel=1e-12)
