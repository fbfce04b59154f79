"""CameraPoseSensor: poses of every part from camera frames, located on its own thread.

In process: rendered frames (firmware_sim.camera_render) from a recorded source, so every
frame is seen.  End to end: firmware_sim's planar world, its MJPEG camera, against /truth.json.
"""

from __future__ import annotations

import json
import math
import threading
import time
import urllib.request
from collections.abc import Sequence

import numpy as np
import pytest

import feeder.drivers.pose_camera as pose_camera
from feeder.daemon.launcher import Simulator
from feeder.drivers.amplifier import DriveSettings
from feeder.drivers.anc300_link import Anc300Link
from feeder.drivers.axes import open_anc300_axes
from feeder.drivers.frame_source import FrameSource
from feeder.drivers.pose_camera import CameraPoseSensor, part_template
from feeder.drivers.sensor import SensorLost
from feeder.drivers.video_camera import open_camera
from feeder.pose import pose_error
from feeder.vision.calibration import CameraCalibration
from firmware_sim.camera_render import CameraModel, FrameRenderer, PartInImage

pytestmark = pytest.mark.timeout(120)

PIXEL_M = 2.5e-6
SIDE_PX = 1024
CALIBRATION = CameraCalibration(PIXEL_M, origin_x_px=(SIDE_PX - 1) / 2, origin_y_px=(SIDE_PX - 1) / 2)
PART_M = 300e-6
TEMPLATE = part_template(PART_M, PART_M, CALIBRATION)
POSITION_TOLERANCE_M = 3e-6  # "a few µm"; measured well below 0.1 µm
ANGLE_TOLERANCE_RAD = math.radians(0.1)


class RenderedFrames(FrameSource):
    """A recorded source: one rendered frame per list of plate poses (none is skipped)."""

    live = False

    def __init__(self, scenes: Sequence[Sequence[tuple[float, float, float]]]) -> None:
        super().__init__("rendered")
        self.renderer = FrameRenderer(
            CameraModel(width_px=SIDE_PX, height_px=SIDE_PX).with_noise(0.02), seed=3
        )
        self.scenes = list(scenes)
        self._next = 0
        self._start()

    def _open(self) -> None:
        self._next = 0

    def _grab(self) -> tuple[np.ndarray, float | None] | None:
        if self._next >= len(self.scenes):
            return None
        side = PART_M / PIXEL_M
        parts = []
        for x, y, psi in self.scenes[self._next]:
            x_px, y_px = CALIBRATION.to_image(x, y)
            parts.append(PartInImage(x_px, y_px, CALIBRATION.angle_to_image(psi), side, side))
        self._next += 1
        return self.renderer.render(parts), None

    def _release(self) -> None:
        pass


class LiveRenderedFrames(RenderedFrames):
    """The same frames from a live camera, which then shows nothing more."""

    live = True

    def _grab(self) -> tuple[np.ndarray, float | None] | None:
        grabbed = super()._grab()
        if grabbed is None:
            self._closed.wait()
        return grabbed


def samples(sensor: CameraPoseSensor, count: int) -> list:
    return [sensor.read(10.0) for _ in range(count)]


def test_ids_by_x_regions_reacquire_unwrapped_angle_off_the_callers_thread(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    threads: set[int] = set()
    real_locate = pose_camera.locate

    def locate(*args, **kwargs):  # type: ignore[no-untyped-def]
        threads.add(threading.get_ident())
        return real_locate(*args, **kwargs)

    monkeypatch.setattr(pose_camera, "locate", locate)
    turn = math.radians(25)  # a square looks the same every 90°: 4 turns pass 90°
    scenes = [
        [(0.6e-3, -0.2e-3, 0.1 + k * turn), (-0.5e-3, 0.3e-3, 0.2)]  # part 1 is the one at -0.5 mm
        for k in range(5)
    ]
    scenes.append([(0.6e-3, -0.2e-3, 0.1 + 4 * turn), (-0.5e-3 + 0.4e-3, 0.3e-3, 0.2)])  # jumps 160 px
    sensor = CameraPoseSensor(RenderedFrames(scenes), CALIBRATION, TEMPLATE)
    try:
        got = samples(sensor, len(scenes))
        latest = sensor.latest_image()
    finally:
        sensor.close()
    assert threading.get_ident() not in threads and len(threads) == 1
    for sample, scene in zip(got, scenes, strict=True):
        expected = [scene[1], scene[0]]  # ids 1, 2 by x at acquisition
        for pose, truth in zip(sample.poses, expected, strict=True):
            distance, angle = pose_error(pose, truth, TEMPLATE.symmetry_rad)
            assert distance < POSITION_TOLERANCE_M and angle < ANGLE_TOLERANCE_RAD
        assert sample.position_m == sample.poses[0][0]
    # the turn is followed through the square's 90° symmetry: 0.1 + 100° read as such
    assert got[4].poses[1][2] == pytest.approx(0.1 + 4 * turn, abs=ANGLE_TOLERANCE_RAD)
    assert [s.sequence for s in got] == list(range(len(scenes)))
    # frame 0 acquires; frames 1-4 are regions; frame 5: part 1 left its region, whole frame again
    assert sensor.full_frame_searches == 2 and sensor.region_searches == 4
    assert latest is not None and latest.full_frame and latest.image.shape == (SIDE_PX, SIDE_PX)
    assert latest.sample is got[-1] and len(latest.detections) == 2


def test_read_raises_sensor_lost_with_the_reason() -> None:
    sensor = CameraPoseSensor(RenderedFrames([[(0.0, 0.0, 0.0)]]), CALIBRATION, TEMPLATE, parts=2)
    try:
        with pytest.raises(SensorLost, match=r"1 parts seen, 2 expected|recording ended"):
            sensor.read(1.0)
    finally:
        sensor.close()
    with pytest.raises(SensorLost, match="closed"):
        sensor.read(0.1)


@pytest.mark.parametrize("live", [False, True])
def test_a_slow_reader_gets_every_sample_of_a_recording_and_the_newest_of_a_live_camera(live: bool) -> None:
    """A reader slower than the locating: a recording's samples wait to be read (none lost, as
    its frames), a live camera's newest sample replaces the unread one (no backlog)."""
    scenes = [[(k * 20e-6, 0.0, 0.1)] for k in range(5)]
    source = LiveRenderedFrames(scenes) if live else RenderedFrames(scenes)
    sensor = CameraPoseSensor(source, CALIBRATION, TEMPLATE, parts=1)
    got = []
    try:
        while len(got) < len(scenes):
            time.sleep(0.5)  # a frame is rendered and located in some 10 ms
            try:
                got.append(sensor.read(1.0))
            except SensorLost:
                break  # a live camera's frames were all located while the reader slept
    finally:
        sensor.close()
    if live:
        assert len(got) < len(scenes) and got[-1].sequence == len(scenes) - 1
    else:
        assert [s.sequence for s in got] == list(range(len(scenes)))
        for sample, scene in zip(got, scenes, strict=True):
            assert sample.poses[0][0] == pytest.approx(scene[0][0], abs=POSITION_TOLERANCE_M)


def _truth(url: str) -> list[tuple[float, float, float]]:
    with urllib.request.urlopen(url + "/truth.json", timeout=10) as response:
        truth = json.loads(response.read())
    return [(p["x_m"], p["y_m"], p["psi_rad"]) for p in truth["parts"]]


def test_mjpeg_poses_agree_with_the_simulator_truth_two_parts() -> None:
    """2048² at 2.5 µm/px over MJPEG, two parts, before and after an x burst (regions track it)."""
    parts = ((-1.0e-3, 0.4e-3, 0.3), (1.2e-3, -0.7e-3, 1.1))
    sim = Simulator(
        [
            "--plant",
            "planar",
            "--parts=" + ";".join(",".join(map(str, p)) for p in parts),
            "--clock",
            "virtual",
            "--dialect",
            "anc300",
            "--camera-http",
            "0",
            "--camera-http-fps",
            "15",
            "--camera-pixel-size-m",
            str(PIXEL_M),
            "--camera-width-px",
            "2048",
            "--camera-height-px",
            "2048",
        ]
    )
    try:
        url = sim.endpoints["camera_http"]
        with urllib.request.urlopen(url + "/truth.json", timeout=10) as response:
            calibration = CameraCalibration(**json.loads(response.read())["calibration"])
        sensor = CameraPoseSensor(
            open_camera(url + "/video.mjpg"), calibration, part_template(PART_M, PART_M, calibration)
        )
        with sensor, open_anc300_axes(Anc300Link(sim.endpoints["console_pty"], timeout_s=5.0)) as axes:
            seen = samples(sensor, 3)[-1].poses
            check(seen, _truth(url))
            assert seen[0][0] < seen[1][0]
            axes["x"].apply(DriveSettings(frequency_hz=1000.0, amplitude_v=60.0))
            axes["x"].enable()
            axes["x"].step(15)
            assert axes["x"].wait(30.0)
            truth = _truth(url)
            for _ in range(100):  # until the world is at rest
                time.sleep(0.3)
                if _truth(url) == truth:
                    break
                truth = _truth(url)
            seen = samples(sensor, 10)[-1].poses  # frames exposed after that
            check(seen, truth)
            assert seen[0][0] - parts[0][0] > 20e-6
            assert sensor.region_searches > sensor.full_frame_searches
    finally:
        sim.stop()


def check(seen: Sequence[tuple[float, float, float]], truth: Sequence[tuple[float, float, float]]) -> None:
    assert len(seen) == len(truth) == 2
    for pose, true in zip(seen, truth, strict=True):
        distance, angle = pose_error(pose, true, TEMPLATE.symmetry_rad)
        assert distance < POSITION_TOLERANCE_M
        assert angle < ANGLE_TOLERANCE_RAD


def test_ids_hold_when_a_burst_moves_the_parts_further_than_they_lie_apart() -> None:
    """Two parts 0.4 mm apart carried 0.6 mm per frame (a coarse burst between two frames): the
    regions each held the other part or the same one, and the whole frame's nearest matching tied
    (both ids on one part, a part driven past the travel while "done")."""
    apart, shift = 0.4e-3, 0.6e-3
    there = [
        [(-0.7e-3 + k * shift, 0.1e-3, 0.0), (-0.7e-3 + apart + k * shift, 0.1e-3, 0.3)] for k in range(3)
    ]
    back = [[(x - 2 * shift, y - 0.1e-3, psi) for x, y, psi in there[-1]]]  # and back, with some y
    scenes = there + back
    sensor = CameraPoseSensor(RenderedFrames(scenes), CALIBRATION, TEMPLATE)
    try:
        got = samples(sensor, len(scenes))
    finally:
        sensor.close()
    for sample, scene in zip(got, scenes, strict=True):
        for pose, truth in zip(sample.poses, scene, strict=True):  # ids 1, 2 by x, kept
            assert pose_error(pose, truth, TEMPLATE.symmetry_rad)[0] < POSITION_TOLERANCE_M, (sample, scene)
