"""Full plant at 100 kS/s (amplifier limits → stack + plate → stick-slip): simulated s per wall s.

The baseline is the real-time clock: ``ratio`` = simulated seconds / wall
seconds for the paper's waveform (100 Hz, 200 Vpp, current-limited flyback) on
a 500×500×50 part, fed in 1 s chunks (a virtual-time sweep).  ``tick_ratio``
feeds the same samples in 1 ms chunks of 100 samples, as the firmware
simulator's tick loop does (per-call overhead dominates there; the compiled
kernels of :mod:`feeder.plant.kernels` cut it when numba is installed).
``compiled`` says which path ran.  The planar plant with three axes live:
benchmarks/plant_realtime_1ms.py.
"""

from __future__ import annotations

import numpy as np
from timing import best_time

from feeder.contact.breakaway import contact
from feeder.parts import Part
from feeder.plant import kernels
from feeder.plant.plant import DEFAULT_SAMPLE_RATE_HZ, Plant
from feeder.plant.stick_slip import Friction
from feeder.waveform import Waveform

TICK_SAMPLES = 100


def run(quick: bool) -> dict:
    seconds = 1 if quick else 5
    rate = DEFAULT_SAMPLE_RATE_HZ
    waveform = Waveform(frequency_hz=100.0, amplitude_vpp=200.0)
    per = round(rate / waveform.frequency_hz)
    index = np.arange(1, int(seconds * rate) + 1)
    command = waveform.voltage_at_phase((index % per) / per)
    friction = Friction(contact(Part.parse("500x500x50")).breakaway_accel_m_s2)
    second = int(rate)

    plants = iter([Plant(friction) for _ in range(5)])  # built outside the timing, as the firmware does

    def bulk() -> None:
        plant = next(plants)
        for start in range(0, command.size, second):
            plant.advance(command[start : start + second])

    ticks = np.split(command, command.size // TICK_SAMPLES)

    def ticked() -> None:
        plant = next(plants)
        for chunk in ticks:
            plant.advance(chunk)

    t_bulk = best_time(bulk)
    t_tick = best_time(ticked, repeats=2)
    return {
        "ratio": seconds / t_bulk,
        "tick_ratio": seconds / t_tick,
        "simulated_s": float(seconds),
        "samples_per_s": command.size / t_bulk,
        "steps_simulated": int(seconds * waveform.frequency_hz),
        "compiled": kernels.enabled(),
    }
