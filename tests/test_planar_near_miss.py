"""A near miss: the relative twist almost vanishes, then turns (planar stick-slip, issue 14).

The solver used to aim at the linearly predicted zero again and again (0.9 of
the predicted time, a Zeno sequence towards the closest approach) and then
declared the twist vanished although it had not: the part re-stuck with a
velocity jump, and whether it did depended on the tolerance (at rtol 1e-6 the
part of :func:`_run` turned 13 % less in 12 ms than at 1e-10), sometimes after
seconds of wall time per 1 ms chunk.  A near miss now goes on in time.
"""

from __future__ import annotations

import numpy as np
import pytest

from feeder.contact.breakaway import contact
from feeder.parts import Part
from feeder.plant import kernels
from feeder.plant.planar import PlanarPart
from feeder.plant.planar_plant import PlanarPlant
from feeder.plant.stick_slip import Friction
from feeder.waveform import Waveform

SHAPE = Part.parse("300x300x50")

COMPILED_ONLY = "the compiled planar solver is off (numba missing or FEEDER_NUMBA=0)"
"""These runs check the compiled solver's step control; the scipy path's own (2.5e-11 m at
rtol 1e-6 against 1e-10 for the near miss) is looser than this test's 1e-11 m."""


def _run(rtol: float, seconds: float = 0.012) -> tuple[tuple[float, float, float], float]:
    """The paper's waveform on x, y and θ, one part 2 mm from O, 1 ms chunks: (pose, slip time)."""
    waveform = Waveform(frequency_hz=100.0, amplitude_vpp=200.0)
    index = np.arange(1, round(seconds * 1e5) + 1)
    line = waveform.voltage_at_phase((index % 1000) / 1000)
    part = PlanarPart.from_part(SHAPE, Friction(contact(SHAPE).breakaway_accel_m_s2), (2e-3, 0.0, 0.0))
    plant = PlanarPlant([part], rtol=rtol)
    for chunk in np.split(np.stack([line, line, line]), index.size // 100, axis=1):
        plant.advance(chunk)
    return plant.poses()[0], plant.contact.slip_time_s[0]


@pytest.mark.skipif(not kernels.enabled(), reason=COMPILED_ONLY)
def test_near_miss_does_not_depend_on_the_tolerance() -> None:
    """The second period's slip passes near zero twist and turns: one pose at rtol 1e-6 and 1e-10."""
    (x0, y0, psi0), slip0 = _run(1e-10)
    (x1, y1, psi1), slip1 = _run(1e-6)
    assert psi0 > 5e-3  # it turned (the second flyback included)
    assert abs(x1 - x0) < 1e-11 and abs(y1 - y0) < 1e-11  # was 6e-9 m
    assert abs(psi1 - psi0) < 1e-7  # was 7e-4 rad
    assert slip1 == pytest.approx(slip0, rel=1e-4)


def test_near_miss_compiled_equals_reference() -> None:
    """The scipy reference path (DOP853) takes the near miss the same way as the compiled solver."""
    before = kernels.enabled()
    try:
        kernels.use_compiled(False)
        (x0, y0, psi0), slip0 = _run(1e-8)
        kernels.use_compiled(kernels.AVAILABLE)
        (x1, y1, psi1), slip1 = _run(1e-8)
    finally:
        kernels.use_compiled(before)
    assert abs(x1 - x0) < 1e-11 and abs(y1 - y0) < 1e-11
    assert abs(psi1 - psi0) < 1e-7
    assert slip1 == pytest.approx(slip0, rel=1e-4)


def _three_axes(rtol: float, seconds: float = 0.13) -> tuple[tuple[float, float, float], list[int]]:
    """x, y and θ at 1 kHz / 137 V, one part 2 mm from O, 1 ms chunks: (pose, steps tried by then at
    0.105 s and at the end)."""
    waveform = Waveform(frequency_hz=1000.0, amplitude_vpp=137.0)
    line = waveform.voltage_at(np.arange(1, round(seconds * 1e5) + 1) / 1e5)
    part = PlanarPart.from_part(SHAPE, Friction(contact(SHAPE).breakaway_accel_m_s2), (2e-3, 0.0, 0.0))
    plant = PlanarPlant([part], rtol=rtol)
    steps = []
    for k, chunk in enumerate(np.split(np.stack([line, line, line]), line.size // 100, axis=1)):
        plant.advance(chunk)
        if k + 1 in (105, line.size // 100):
            steps.append(plant.contact.integration_steps[0])
    return plant.poses()[0], steps


@pytest.mark.skipif(not kernels.enabled(), reason=COMPILED_ONLY)
def test_a_twist_below_the_steps_error_has_vanished() -> None:
    """From ~0.106 s the twist shrinks to ~1e-8 m/s (a few error scales at rtol 1e-6) and spins;
    integrated on in time, the steps sat at their stability limit, ~15000 per 1 ms tick (~300 now),
    for the same poses."""
    (x0, y0, psi0), _ = _three_axes(1e-10)
    (x1, y1, psi1), (before, after) = _three_axes(1e-6)
    assert after - before < 25 * 1000  # 25 ticks; was ~375000
    assert abs(x1 - x0) < 1e-9 and abs(y1 - y0) < 1e-9
    assert abs(psi1 - psi0) < 1e-6
