"""The compiled kernels (numba, extra ``fast``) against the numpy/scipy path: same results to rounding
(1-D) or to the integrators' tolerance (planar)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from feeder.parts import Part
from feeder.plant import kernels, planar_arrays, slip_kernels
from feeder.plant.ideal_plate import sawtooth_motion
from feeder.plant.limit_surface import Patch
from feeder.plant.limit_surface_kernels import DISC_NODES, gauge
from feeder.plant.planar import PlanarPart, simulate
from feeder.plant.planar_plant import PlanarPlant
from feeder.plant.plant import Plant
from feeder.plant.plate_motion import sawtooth as planar_sawtooth
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


def test_the_plates_small_turn_series_equals_the_library_to_rounding() -> None:
    """cos and sin of the plate's angle by the Taylor series below 1e-2 rad: within 2 ulp of the
    library's, at both ends of the range and across it (compiled and plain Python)."""
    turn = planar_arrays._turn
    angles = np.concatenate([np.linspace(-0.0099999, 0.0099999, 2001), [0.0, 1e-12, -3e-7, 0.01, -0.5, 2.0]])
    for angle in angles:
        for c, s in (turn(angle), turn.py_func(angle)):
            assert abs(c - math.cos(angle)) <= 2 * math.ulp(1.0)
            assert abs(s - math.sin(angle)) <= 2 * math.ulp(max(abs(math.sin(angle)), 1e-300))


def _corner_sum(wx: float, wy: float, omega: float, a: float, b: float) -> np.ndarray:
    """The rectangle's integrals as the plain sum of the four corners' functions (8 asinh)."""

    def corner(x: float, y: float) -> tuple[float, float, float]:
        r = math.hypot(x, y)
        lx = math.asinh(y / abs(x)) if x else 0.0
        ly = math.asinh(x / abs(y)) if y else 0.0
        moment = x * y * r / 3 + (x**3 * lx + y**3 * ly) / 6
        return 0.5 * (y * r + x * x * lx), 0.5 * (x * r + y * y * ly), moment

    xc, yc = -wy / omega, wx / omega
    x1, x2, y1, y2 = -a - xc, a - xc, -b - yc, b - yc
    i = np.array(corner(x2, y2)) - corner(x1, y2) - corner(x2, y1) + corner(x1, y1)
    sign = math.copysign(1.0, omega)
    return np.array([-sign * i[1], sign * i[0], sign * (i[2] + xc * i[0] + yc * i[1]), abs(omega) * i[2]])


CENTRES = [(0.0, 0.0), (150e-6, 20e-6), (150e-6, 100e-6), (-150e-6, -300e-6), (400e-6, 250e-6),
           (-2e-3, 1e-3), (90e-6, -700e-6), (5e-3, -3e-3)]  # fmt: skip


@pytest.mark.parametrize("centre", CENTRES)
def test_rectangle_integrals_equal_the_corner_sum(centre: tuple[float, float]) -> None:
    """One logarithm per edge line (both signs of the corners' coordinates, the centre of rotation
    inside, on an edge line, at a corner, far outside) is the sum of the corners' asinh terms."""
    a, b = 150e-6, 100e-6
    for omega in (3.0, -0.7):
        wx, wy = omega * centre[1], -omega * centre[0]  # ρ_c = ẑ×w/ω = centre
        got = np.array(kernels.rectangle_integrals(wx, wy, omega, a, b))
        ref = _corner_sum(wx, wy, omega, a, b)
        speed = math.hypot(wx, wy) + abs(omega) * math.hypot(a, b)
        scale = np.array([4 * a * b, 4 * a * b, 4 * a * b * math.hypot(a, b), 4 * a * b * speed])
        np.testing.assert_allclose(got / scale, ref / scale, rtol=0, atol=1e-11)
        assert np.all(np.isfinite(got))


# --- planar stick-slip: the compiled solver (planar_kernels & co) against the scipy reference -----------


PLANAR_PART = Part.parse("300x200x50")


@pytest.mark.parametrize("pose, stroke, shape, ratio", [
    ((2e-3, 0.0, 0.0), (0.0, 0.0, 7e-3), "linear", 0.8),  # far from O: orbits and turns
    ((0.0, 0.0, 0.2), (0.0, 0.0, 0.1), "linear", 0.8),  # at O: turns in place
    ((2e-3, 0.0, 0.0), (0.0, 0.0, 7e-3), "half-cosine", 1.0),  # breakaway from stick (Brent, gauge)
    ((1e-3, -1e-3, 0.0), (5e-6, 0.0, 7e-3), "linear", 0.8),  # x and θ at once
    ((1e-3, 0.5e-3, 0.6), (14e-6, 0.0, 0.0), "half-cosine", 1.0),  # x through the general integrator
])  # fmt: skip
def test_planar_compiled_equals_reference(both, pose, stroke, shape, ratio) -> None:
    part = PlanarPart.from_part(PLANAR_PART, Friction(105.25, ratio), pose)
    motion = planar_sawtooth(stroke, 100.0, 3.5e-4, shape, 3)
    slow, fast = both(lambda: simulate([part], motion))
    step = np.abs(slow.changes).max(axis=(0, 1))
    assert step.max() > 1e-6  # it moved
    # integrators of different order (DP5, DOP853) at rtol 1e-10: within 1e-7 of a step
    np.testing.assert_allclose(fast.changes[..., :2], slow.changes[..., :2], rtol=0,
                               atol=1e-7 * max(step[:2].max(), 1e-6))  # fmt: skip
    np.testing.assert_allclose(fast.changes[..., 2], slow.changes[..., 2], rtol=0, atol=1e-7 * step[2])
    np.testing.assert_allclose(fast.slip_fraction, slow.slip_fraction, rtol=1e-6)


def test_planar_plant_compiled_equals_reference_in_1ms_ticks(both) -> None:
    """PlanarPlant, firmware-like chunks, x, y and θ live, two parts (one a disc) at rtol 1e-10."""
    waveform = Waveform(frequency_hz=100.0, amplitude_vpp=200.0)
    index = np.arange(1, 2501)
    line = waveform.voltage_at_phase((index % 1000) / 1000)
    command = np.stack([line, 0.5 * line, line])
    friction = Friction(105.25, 0.8)
    disc = PlanarPart.from_part(Part.parse("200x200x50"), friction, (-1e-3, 1e-3, 0.0), shape="disc")
    parts = [PlanarPart.from_part(PLANAR_PART, friction, (2e-3, 0.0, 0.0)), disc]

    def run() -> tuple[np.ndarray, list[float], tuple[float, float, float]]:
        plant = PlanarPlant(parts, rtol=1e-10)
        lab = np.concatenate([plant.advance(c) for c in np.split(command, 25, axis=1)], axis=1)
        return lab, plant.contact.slip_time_s, plant.output_voltages_v

    (slow, slip0, v0), (fast, slip1, v1) = both(run)
    assert np.ptp(slow[0, :, 2]) > 1e-3 and min(slip0) > 0  # both parts slipped, the first turned
    np.testing.assert_allclose(fast[..., :2], slow[..., :2], rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast[..., 2], slow[..., 2], rtol=0, atol=1e-8)
    np.testing.assert_allclose(slip1, slip0, rtol=1e-6)
    np.testing.assert_allclose(v1, v0, rtol=0, atol=1e-9)


def test_planar_plant_hands_its_drive_back_when_the_kernels_are_switched_off() -> None:
    """The compiled path's filter states and voltages (one drive array) go back to the output
    stages and stack filters: switched off mid-run, the plant goes on as if it had not been."""
    waveform = Waveform(frequency_hz=100.0, amplitude_vpp=200.0)
    line = waveform.voltage_at_phase((np.arange(1, 1001) % 1000) / 1000)
    chunks = np.split(np.stack([line, 0.5 * line, line]), 10, axis=1)
    part = PlanarPart.from_part(PLANAR_PART, Friction(105.25, 0.8), (2e-3, 0.0, 0.0))
    before = kernels.enabled()
    try:
        whole, switched = PlanarPlant([part]), PlanarPlant([part])
        ref = np.concatenate([whole.advance(c) for c in chunks], axis=1)
        lab = [switched.advance(c) for c in chunks[:5]]
        volts = switched.output_voltages_v
        kernels.use_compiled(False)
        assert switched.output_voltages_v == volts  # handed back, not reset
        lab += [switched.advance(c) for c in chunks[5:]]
    finally:
        kernels.use_compiled(before)
    assert max(volts) > 10
    np.testing.assert_allclose(np.concatenate(lab, axis=1), ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(switched.output_voltages_v, whole.output_voltages_v, rtol=0, atol=1e-9)


def test_planar_arrays_have_the_sizes_their_layout_names() -> None:
    """A part's parameter row, its state, the plate and a drive row are as long as
    :mod:`.planar_arrays` says: a column added in one place and not the other fails here."""
    part = PlanarPart.from_part(PLANAR_PART, Friction(105.25, 0.8), (2e-3, 0.0, 0.0))
    plant = PlanarPlant([part])
    plant.advance(np.full((3, 10), 5.0))
    pa = planar_arrays
    assert plant.contact._params.shape == (1, pa.PARAM_SIZE)
    assert plant.contact._array.shape == (1, pa.STATE_SIZE)
    assert plant.contact._plate_array.shape == (pa.PLATE_SIZE,)
    if kernels.enabled():  # the drive array exists on the compiled path only
        assert plant._drive is not None and plant._drive.shape == (3, pa.DRIVE_SIZE)


def test_planar_gauge_compiled_equals_scipy() -> None:
    """The compiled BFGS gauge finds the scipy one's limit-surface point (rectangle and disc)."""
    for patch in (Patch("rectangle", 300e-6, 200e-6), Patch("disc", 200e-6, 200e-6)):
        params = planar_arrays.part_params(patch.shape == "disc", patch.length_m, patch.width_m, 1e-9,
                                            1e-17, 100.0, 0.8, patch.area_m2, patch.polar_m3,
                                            patch.second_moments_m4, 1e-10)  # fmt: skip
        for wrench in [(1e-7, 0.0, 1e-11), (0.5e-7, 0.3e-7, -2e-11), (1e-8, -2e-9, 3e-13), (0.0, 0.0, 1e-11)]:
            g, wx, wy, om = gauge(params, patch.radius_m, DISC_NODES, *wrench)
            ref, _ = patch.gauge(*wrench)
            assert g == pytest.approx(ref, rel=1e-9)
            ux, uy, mu, _ = patch.integrals(wx, wy, om)
            np.testing.assert_allclose(np.array([ux, uy, mu]) * g, wrench, rtol=1e-6, atol=1e-6 * max(wrench))


@pytest.mark.skipif(not kernels.AVAILABLE, reason="numba (extra 'fast') not installed")
def test_planar_slip_hands_its_derivative_to_the_next_sample() -> None:
    """A slip that reaches a sample's end stores d(lab state)/dt there (DERIV, at the plate's elapsed
    time DERIV_AT); the next sample starts its steps from it instead of six limit-surface integrals
    more.  It is the derivative a fresh evaluation gives at the next sample's start."""
    pk = planar_arrays
    waveform = Waveform(frequency_hz=100.0, amplitude_vpp=200.0)
    line = waveform.voltage_at_phase((np.arange(1, 1201) % 1000) / 1000)
    part = PlanarPart.from_part(PLANAR_PART, Friction(105.25, 0.8), (2e-3, 0.0, 0.0))
    plant = PlanarPlant([part])
    checked = 0
    for k in range(line.size):  # one sample per call: the state between samples is visible
        plant.advance(np.full((3, 1), line[k]))
        st, plate = plant.contact._array[0], plant.contact._plate_array
        if st[pk.STUCK] != 0 or st[pk.DERIV_AT] != plate[pk.ELAPSED]:
            continue
        seg = np.zeros(pk.SEG_SIZE)
        seg[pk.DURATION] = 1e-5
        seg[pk.V : pk.V + 3] = plate[3:6]
        y = np.array([0.0, 0.0, 0.0, *st[pk.LAB + 3 : pk.LAB + 6]])
        fresh = np.empty(7)
        slip_kernels._rhs(plant.contact._params[0], st[pk.RADIUS], DISC_NODES, seg, plate,
                          *st[pk.LAB : pk.LAB + 3], 0.0, y, fresh)  # fmt: skip
        # the same to rounding (the sample end: v₀ + a·dt there, the sample itself here)
        np.testing.assert_allclose(st[pk.DERIV : pk.DERIV + 6], fresh[:6], rtol=1e-6, atol=1e-12)
        checked += 1
    assert checked > 50  # the flyback's slip spans many samples
