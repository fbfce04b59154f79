"""The world behind the firmware: camera timing/noise, true τ, true step vs the plant model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from feeder.contact.breakaway import DEFAULT_TAU_BAND_PA, DEFAULT_TAU_PA
from feeder.plant.plant import run_waveform
from feeder.waveform import Waveform
from firmware_sim.clock import VirtualClock
from firmware_sim.firmware import Firmware, FirmwareConfig
from firmware_sim.world import CameraConfig, World, WorldConfig


def test_camera_rate_latency_and_noise() -> None:
    config = FirmwareConfig()
    firmware = Firmware(config)
    now = [0.0]
    firmware.add_tick_listener(lambda t: now.__setitem__(0, t))  # before the world's
    frames: list[tuple[float, dict[str, float]]] = []
    camera = CameraConfig(rate_hz=500.0, noise_m=1e-7, latency_s=0.013)
    world = World(WorldConfig(camera=camera), config,
                  publish=lambda line: frames.append((now[0], json.loads(line))))
    world.attach(firmware)
    firmware.run(VirtualClock(), max_ticks=400)
    seqs = [f["seq"] for _, f in frames]
    assert seqs == list(range(len(seqs))) and len(seqs) >= 190  # (0.4 − 0.013) s at 500 Hz
    for sent_s, frame in frames:
        assert frame["time_s"] == pytest.approx(frame["seq"] / 500.0)
        assert frame["time_s"] + 0.013 <= sent_s + 1e-9 < frame["time_s"] + 0.013 + 0.001
    positions = np.array([f["position_m"] for _, f in frames])
    assert np.std(positions) == pytest.approx(1e-7, rel=0.2)
    assert np.mean(positions) == pytest.approx(world.plant.part_position_m, abs=4e-7 / 14)


def test_true_tau_is_drawn_in_the_band_set_or_offset() -> None:
    drawn = [WorldConfig(seed=s).true_tau_pa() for s in range(20)]
    assert all(abs(t - DEFAULT_TAU_PA) <= DEFAULT_TAU_BAND_PA for t in drawn)
    assert len(set(drawn)) == 20
    assert WorldConfig(tau_offset=-0.15).true_tau_pa() == pytest.approx(0.85 * DEFAULT_TAU_PA)
    assert WorldConfig(tau_pa=2e10).true_tau_pa() == 2e10


def test_true_step_matches_the_plant_model_on_the_ideal_waveform() -> None:
    # current-limited flyback: the firmware's DAC stream and the ideal sampled
    # sawtooth give the plant the same output after the current limit
    config = FirmwareConfig()
    world = World(WorldConfig(scatter=0.0, seed=4), config)
    axis = Firmware(config).axis(1)
    axis.set_amplitude(180.0)
    axis.set_mode("stp")
    step = world.true_step(axis)
    run = run_waveform(world.friction, Waveform(frequency_hz=100.0, amplitude_vpp=180.0),
                       5, config.amplifier, world.config.stack)
    assert step.up_m == pytest.approx(float(np.mean(run.steps_m)), rel=2e-3)
    assert step.down_m == pytest.approx(-step.up_m, rel=2e-3)
    assert step.scatter == 0.0
    noisy = World(WorldConfig(scatter=0.05, seed=4), config).true_step(axis)
    assert 0.0 < noisy.scatter < 1.0
