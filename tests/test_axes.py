"""Three plate axes (x, y, θ) on one amplifier: the strict ANC300 console and CANopen, against the
planar plant's true poses (firmware_sim ``--plant planar``, camera stream without noise)."""

from __future__ import annotations

import math
import time

import pytest

from feeder.daemon.launcher import Simulator
from feeder.drivers.amplifier import DriveSettings
from feeder.drivers.anc300_link import Anc300Link
from feeder.drivers.axes import Axes, check_axis_map, open_anc300_axes, open_canopen_axes
from feeder.drivers.camera import StreamCamera
from feeder.drivers.sensor import PositionSensor
from feeder.errors import InputError
from feeder.protocol.eds import EDS_FILE

pytestmark = pytest.mark.timeout(120)

# 1 kHz, 60 V: x and y steps of ≈ 3 µm, θ steps of ≈ 0.9 mrad on the default planar plant
DRIVE = DriveSettings(frequency_hz=1000.0, amplitude_v=60.0)
PART = (0.8e-3, 0.4e-3, 0.2)
XY_STEPS = 10
THETA_STEPS = 2
SETTLED_S = 0.02  # world time the poses must stay put to count as settled
STILL = 1e-10  # m or rad: "put" (the integrator's drift at rest is ~1e-13 m/s)


def start(transport: str, *extra: str) -> Simulator:
    front = ["--dialect", "anc300"] if transport == "serial" else ["--can", "slcan-pty", *extra]
    return Simulator(
        [
            "--plant",
            "planar",
            f"--parts={PART[0]},{PART[1]},{PART[2]}",
            "--sensor",
            "tcp:127.0.0.1:0",
            "--camera-noise-m",
            "0",
            "--camera-latency-s",
            "0",
            "--clock",
            "virtual",  # ticks back to back: the planar plant runs ~30× real time, so the tests go faster
            *front,
        ]
    )


def open_axes(sim: Simulator, transport: str, eds: str = EDS_FILE) -> Axes:
    if transport == "serial":
        return open_anc300_axes(Anc300Link(sim.endpoints["console_pty"], timeout_s=5.0))
    bus = {
        "interface": "slcan",
        "channel": sim.endpoints["slcan_pty"],
        "bitrate": 500000,
        "sleep_after_open": 0,
    }
    return open_canopen_axes(bus, eds=eds, heartbeat_s=1.0, timeout_s=2.0)


def settled(camera: PositionSensor, timeout_s: float = 60.0) -> tuple[float, float, float]:
    """The part's true pose once it stayed put for :data:`SETTLED_S` of world time."""
    deadline = time.monotonic() + timeout_s
    sample = camera.read(30.0)
    since, pose = sample.time_s, sample.poses[0]
    while time.monotonic() < deadline:
        sample = camera.read(30.0)
        if max(abs(a - b) for a, b in zip(sample.poses[0], pose, strict=True)) > STILL:
            since, pose = sample.time_s, sample.poses[0]
        elif sample.time_s - since >= SETTLED_S:
            return pose
    raise AssertionError("the part did not settle")


def burst(axes: Axes, name: str, steps: int) -> None:
    """``steps`` on one axis; the other axes stay idle meanwhile."""
    axes[name].step(steps)
    others = [axes[other].status() for other in axes if other != name]
    assert not any(status.moving for status in others)
    assert axes[name].wait(60.0)


@pytest.mark.parametrize("transport", ["serial", "can"])
def test_three_axes_each_move_only_their_plate_axis_stop_together_ground_on_close(transport: str) -> None:
    sim = start(transport)
    try:
        axes = open_axes(sim, transport)
        with StreamCamera(sim.endpoints["sensor_tcp"]) as camera, axes:
            for amplifier in axes.values():
                amplifier.apply(DRIVE)
                amplifier.enable()
            each_axis_moves_only_its_own_plate_axis(axes, camera)
            stop_on_all_axes(axes, camera)
        again = open_axes(sim, transport)  # closing grounded every axis
        with again:
            assert [amplifier.status().mode for amplifier in again.values()] == ["gnd"] * 3
    finally:
        sim.stop()


def each_axis_moves_only_its_own_plate_axis(axes: Axes, camera: PositionSensor) -> None:
    assert set(axes) == {"x", "y", "theta"}
    start = settled(camera)
    assert start == pytest.approx(PART, abs=1e-9)

    burst(axes, "x", XY_STEPS)
    after_x = settled(camera)
    assert after_x[0] - start[0] > 0.5 * XY_STEPS * 1e-6  # +x: the part steps towards +x
    assert after_x[1:] == pytest.approx(start[1:], abs=1e-9)

    burst(axes, "y", -XY_STEPS)
    after_y = settled(camera)
    assert after_y[1] - after_x[1] < -0.5 * XY_STEPS * 1e-6
    assert (after_y[0], after_y[2]) == pytest.approx((after_x[0], after_x[2]), abs=1e-9)


def stop_on_all_axes(axes: Axes, camera: PositionSensor) -> None:
    before = settled(camera)
    axes["x"].step(100_000)  # one axis: its slips simulate ~3x faster than planar ones
    deadline = time.monotonic() + 30.0  # stopped once the camera sees it run: a frame taken
    while abs(camera.read(30.0).poses[0][0] - before[0]) <= STILL:  # before its first step
        assert time.monotonic() < deadline, "x did not run"  # let the stop beat it (CI, loaded)
    axes.stop()
    stopped = settled(camera)
    assert not any(amplifier.status().moving for amplifier in axes.values())
    assert stopped[0] > before[0]  # it ran, and stopped far short of 100000 steps (~300 mm): how
    # far depends on the world time the virtual clock runs during the three stops' round trips
    # (3.5-53 µm seen, more on a loaded machine), so the bound is ~300 steps, not a latency
    assert stopped[0] - before[0] < 1e-3
    time.sleep(0.2)
    assert settled(camera) == pytest.approx(stopped, abs=1e-9)


def test_theta_turns_the_plate_about_o() -> None:
    sim = start("serial")
    try:
        with StreamCamera(sim.endpoints["sensor_tcp"]) as camera, open_axes(sim, "serial") as axes:
            axes["theta"].apply(DRIVE)
            axes["theta"].enable()
            after_y = settled(camera)
            burst(axes, "theta", THETA_STEPS)
            after_t = settled(camera)
            turn = after_t[2] - after_y[2]
            assert turn > 0.1e-3 * THETA_STEPS  # +θ turns from +x towards +y
            # the plate turns about O: the part also orbits O the same way (by less than it turns: it
            # slips during the flyback), along the circle, not radially
            orbit = math.atan2(after_t[1], after_t[0]) - math.atan2(after_y[1], after_y[0])
            radius = math.hypot(*after_y[:2])
            assert 0.2 * turn < orbit < turn
            assert abs(math.hypot(*after_t[:2]) - radius) < 0.1 * radius * orbit
    finally:
        sim.stop()


def test_axis_map_is_checked() -> None:
    assert check_axis_map({"x": 4, "y": 2, "theta": 1}) == {"x": 4, "y": 2, "theta": 1}
    for bad, field in (
        ({"z": 1}, "axis_map"),
        ({"x": 1, "y": 1}, "axis_map"),
        ({"x": 0}, "axis_map.x"),
        ({"x": 8}, "axis_map.x"),
        ({"x": True}, "axis_map.x"),
    ):
        with pytest.raises(InputError) as error:
            check_axis_map(bad)
        assert error.value.field == field
