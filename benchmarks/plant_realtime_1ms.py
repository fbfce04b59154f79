"""The planar plant (firmware_sim --plant planar) stepped in 1 ms chunks, all three axes live.

``ratio`` = simulated seconds / wall seconds (the baseline is the real-time
clock): the paper's waveform (100 Hz, 200 Vpp, current-limited flyback) on
axes x, y and θ at once, 100 samples per call as the firmware tick feeds
them, one 300×300×50 part 2 mm from O; the best of 3 runs, each from a fresh
plant.  ``x_only_ratio``, ``y_only_ratio``, ``theta_only_ratio``: one axis
live (x, y: the pure translation, 1-D closed form inside; θ: the part orbits
and turns, slip episodes integrated).
Acceptance (issue 14): ≥ 100.  The compiled kernels (extra ``fast``) are on
unless ``FEEDER_NUMBA=0``.
"""

from __future__ import annotations

import numpy as np
from timing import best_time

from feeder.contact.breakaway import contact
from feeder.parts import Part
from feeder.plant.planar import PlanarPart
from feeder.plant.planar_plant import PlanarPlant
from feeder.plant.plant import DEFAULT_SAMPLE_RATE_HZ
from feeder.plant.stick_slip import Friction
from feeder.waveform import Waveform

TICK_SAMPLES = 100
REPEATS = 3
POSE = (2e-3, 0.0, 0.0)


def _ratio(command: np.ndarray, part: PlanarPart) -> float:
    chunks = np.split(command, command.shape[1] // TICK_SAMPLES, axis=1)
    warm = PlanarPlant([part])  # compiles (or loads) the kernels outside the timing
    for chunk in chunks[:20]:
        warm.advance(chunk)
    # built outside the timing: the firmware builds its plant once
    plants = iter([PlanarPlant([part]) for _ in range(REPEATS)])

    def stream() -> None:
        plant = next(plants)
        for chunk in chunks:
            plant.advance(chunk)

    return command.shape[1] / DEFAULT_SAMPLE_RATE_HZ / best_time(stream, REPEATS)


def run(quick: bool) -> dict:
    seconds = 0.02 if quick else 0.1
    waveform = Waveform(frequency_hz=100.0, amplitude_vpp=200.0)
    per = round(DEFAULT_SAMPLE_RATE_HZ / waveform.frequency_hz)
    index = np.arange(1, int(seconds * DEFAULT_SAMPLE_RATE_HZ) + 1)
    line = waveform.voltage_at_phase((index % per) / per)
    shape = Part.parse("300x300x50")
    part = PlanarPart.from_part(shape, Friction(contact(shape).breakaway_accel_m_s2), POSE)
    result = {"ratio": _ratio(np.stack([line, line, line]), part)}
    for axis, name in enumerate(("x", "y", "theta")):
        one = np.zeros((3, line.size))
        one[axis] = line
        result[f"{name}_only_ratio"] = _ratio(one, part)
    return {**result, "simulated_s": seconds}
