"""The world behind the firmware: camera timing/noise, true τ, true step vs the plant model."""

from __future__ import annotations

import json
import socket
import subprocess
import sys

import numpy as np
import pytest

from feeder.contact.breakaway import DEFAULT_TAU_BAND_PA, DEFAULT_TAU_PA
from feeder.daemon.launcher import Simulator
from feeder.drivers.anc300_link import Anc300Link
from feeder.errors import InputError
from feeder.plant import kernels
from feeder.plant.plant import run_waveform
from feeder.pose import parse_poses
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
    world = World(
        WorldConfig(camera=camera), config, publish=lambda line: frames.append((now[0], json.loads(line)))
    )
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
    run = run_waveform(
        world.friction,
        Waveform(frequency_hz=100.0, amplitude_vpp=180.0),
        5,
        config.amplifier,
        world.config.stack,
    )
    assert step.up_m == pytest.approx(float(np.mean(run.steps_m)), rel=2e-3)
    assert step.down_m == pytest.approx(-step.up_m, rel=2e-3)
    assert step.scatter == 0.0
    noisy = World(WorldConfig(scatter=0.05, seed=4), config).true_step(axis)
    assert 0.0 < noisy.scatter < 1.0


# --- the planar plant behind axes 1–3 -------------------------------------------------------


def sensor_poses(url: str, after: float) -> tuple[float, list[list[float]]]:
    """(time, poses) of the first sensor frame exposed after ``after`` s of world time."""
    host, port = url.removeprefix("socket://").rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=30) as sock:
        stream = sock.makefile("r")
        for line in stream:
            frame = json.loads(line)
            if frame["time_s"] > after:
                return frame["time_s"], frame["poses"]
    raise AssertionError("sensor stream ended")


def settled_poses(link: Anc300Link, url: str) -> np.ndarray:
    """Poses a few frames after everything is idle (the part stuck, the plate at rest)."""
    t, _ = sensor_poses(url, 0.0)
    return np.array(sensor_poses(url, t + 0.03)[1])


@pytest.mark.timeout(180)
def test_console_steps_turn_and_move_parts_on_the_planar_plant() -> None:
    """axis 3 turns a part 2 mm from O and moves it on an orbit; axis 1 moves it N steps in x."""
    sim = Simulator(["--clock", "virtual", "--plant", "planar", "--parts", "2e-3,0,0;-2e-3,0,0.5",
                     "--dialect", "extended", "--sensor", "tcp:127.0.0.1:0", "--camera-noise-m", "0",
                     "--scatter", "0", "--seed", "2"])  # fmt: skip
    try:
        true = sim.ready["true"]
        assert true["plant"] == "planar" and true["poses"][1] == [-2e-3, 0.0, 0.5]
        url = sim.endpoints["sensor_tcp"]
        link = Anc300Link(sim.endpoints["console_pty"], timeout_s=60.0)
        start = settled_poses(link, url)
        np.testing.assert_allclose(start, [[2e-3, 0, 0], [-2e-3, 0, 0.5]], atol=1e-12)
        volts = true["step_reference"]["amplitude_v"]
        for command in (f"setv 3 {volts}", "setm 3 stp", "stepu 3 3", "stepw 3"):
            link.query(command)
        turned = settled_poses(link, url)
        change = turned - start
        radius = np.hypot(turned[:, 0], turned[:, 1])
        polar = np.angle((turned[:, 0] + 1j * turned[:, 1]) / (start[:, 0] + 1j * start[:, 1]))
        for k in range(2):  # both parts turn the plate's way and orbit O at their distance
            assert change[k, 2] > 1e-4 and polar[k] > 1e-4
            assert abs(radius[k] - 2e-3) < 0.05 * 2e-3 * polar[k]
        n = 3
        for command in (f"setv 1 {volts}", "setm 1 stp", f"stepu 1 {n}", "stepw 1"):
            link.query(command)
        moved = settled_poses(link, url) - turned
        link.close()
        # a pure translation: the 1-D model's step (true step_up_m, measured on the same DAC stream)
        np.testing.assert_allclose(moved[:, 0], n * true["step_up_m"], rtol=0.03)
        np.testing.assert_allclose(moved[:, 1:], 0.0, atol=1e-12)
    finally:
        sim.stop()


@pytest.mark.skipif(not kernels.enabled(), reason="numba (extra 'fast') not in use: nothing is compiled")
def test_a_planar_world_has_its_plants_kernels_ready_before_the_first_tick() -> None:
    """Built in a fresh process, the planar world has numba compile (or load) the plant's kernel
    already: the first tick that drives the plate does not spend ~50 ms (hot cache) to a minute
    (cold) on it."""
    probe = (
        "from feeder.plant import planar_kernels as pk\n"
        "from firmware_sim.firmware import FirmwareConfig\n"
        "from firmware_sim.world import World, WorldConfig\n"
        "World(WorldConfig(plant='planar'), FirmwareConfig(axes=3))\n"
        "print(len(pk.run_plant.signatures))\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=600,
                          check=True)  # fmt: skip
    assert int(done.stdout.split()[-1]) == 1


def test_planar_world_refuses_too_few_axes_and_bad_poses() -> None:
    with pytest.raises(InputError, match="--axes"):
        World(WorldConfig(plant="planar"), FirmwareConfig(axes=2))
    with pytest.raises(InputError, match="--parts"):
        parse_poses("1e-3,0", "--parts")
    with pytest.raises(InputError, match="--plant"):
        World(WorldConfig(plant="cube"), FirmwareConfig())
    assert parse_poses("1e-3,0,0;-1e-3,2e-3,0.5", "--parts") == ((1e-3, 0.0, 0.0), (-1e-3, 2e-3, 0.5))
