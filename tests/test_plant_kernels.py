"""The compiled kernels (numba, extra ``fast``) against the numpy path: same results to rounding."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest

from feeder.plant import kernels
from feeder.plant.ideal_plate import sawtooth_motion
from feeder.plant.plant import Plant
from feeder.plant.stick_slip import Friction, StickSlip
from feeder.waveform import Waveform

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason="numba (extra 'fast') not installed")


@pytest.fixture
def both() -> Iterator[Callable[[Callable[[], object]], tuple[object, object]]]:
    """Run a function on the numpy path and on the compiled path; returns (numpy, compiled)."""
    before = kernels.enabled()

    def run(func: Callable[[], object]) -> tuple[object, object]:
        kernels.use_compiled(False)
        slow = func()
        kernels.use_compiled(True)
        return slow, func()

    yield run
    kernels.use_compiled(before)


def random_motion(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    accel = rng.normal(0, 150, n)
    dt = rng.uniform(1e-6, 5e-5, n)
    jump = np.where(rng.random(n) < 0.05, rng.normal(0, 0.01, n), 0.0)
    return accel, dt, jump


def test_stick_slip_kernel_equals_numpy_in_chunks_with_scatter(both) -> None:
    rng = np.random.default_rng(11)
    accel, dt, jump = random_motion(rng, 4000)
    cuts = np.sort(rng.choice(np.arange(1, 4000), 30, replace=False))

    def run() -> tuple[np.ndarray, float, float, bool]:
        solver = StickSlip(Friction(105.0, 0.7), scatter=0.2, seed=4)
        out = np.concatenate(
            [
                solver.advance(a, d, j)
                for a, d, j in zip(
                    np.split(accel, cuts), np.split(dt, cuts), np.split(jump, cuts), strict=True
                )
            ]
        )
        return out, solver.slip_time_s, solver.static_accel_m_s2, solver.stuck

    (slow, slip0, a0, stuck0), (fast, slip1, a1, stuck1) = both(run)
    assert 0.05 < slip0 / 4000 / 2.5e-5 < 0.95  # both sticking and slipping happen
    np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=1e-20)
    assert slip1 == pytest.approx(slip0, rel=1e-12)
    assert (a1, stuck1) == (a0, stuck0)  # the same scatter draws, in the same order


def test_stick_slip_kernel_on_half_cosine_sawtooth(both) -> None:
    motion = sawtooth_motion(14e-6, 100.0, 3.5e-4, "half-cosine", periods=5)
    slow, fast = both(
        lambda: StickSlip(Friction(105.0, 0.8)).advance(
            motion.accel_m_s2[0], motion.duration_s[0], motion.jump_m_s[0]
        )
    )
    assert np.ptp(slow) > 1e-6
    np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=1e-20)


def test_plant_kernel_equals_numpy_in_1ms_ticks(both) -> None:
    waveform = Waveform(frequency_hz=100.0, amplitude_vpp=200.0)
    index = np.arange(1, 20_001)
    command = waveform.voltage_at_phase((index % 1000) / 1000)
    command[12_000:] = command[12_000:][::-1]  # and backwards

    def run() -> tuple[np.ndarray, np.ndarray, float, float]:
        plant = Plant(Friction(105.0, 0.8), scatter=0.05, seed=3)
        traces = [plant.advance_traces(c) for c in np.split(command, 200)]
        part = np.concatenate([t[0] for t in traces])
        plate = np.concatenate([t[1] for t in traces])
        return part, plate, plant.slip_time_s, plant.output_voltage_v

    (part0, plate0, slip0, v0), (part1, plate1, slip1, v1) = both(run)
    assert np.ptp(part0[:12_000]) > 20e-6  # it moved: several 3.3 µm steps
    np.testing.assert_allclose(plate1, plate0, rtol=0, atol=1e-12 * np.abs(plate0).max())
    np.testing.assert_allclose(part1, part0, rtol=0, atol=1e-12 * np.abs(part0).max())
    assert slip1 == pytest.approx(slip0, rel=1e-12)
    assert v1 == v0


def test_switch_off_selects_numpy() -> None:
    before = kernels.enabled()
    try:
        kernels.use_compiled(False)
        assert not kernels.enabled()
        kernels.use_compiled(True)
        assert kernels.enabled()
    finally:
        kernels.use_compiled(before)


def test_rectangle_integrals_compiled_equal_plain_python() -> None:
    rng = np.random.default_rng(5)
    for wx, wy, omega in rng.normal(0, 1, (50, 3)) * [1e-3, 1e-3, 5.0]:
        fast = kernels.rectangle_integrals(wx, wy, omega, 150e-6, 100e-6)
        slow = kernels.rectangle_integrals.py_func(wx, wy, omega, 150e-6, 100e-6)
        np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=0)
        assert fast[3] > 0  # dissipated power
