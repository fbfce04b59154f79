"""Host camera sources: folders, video files, a live MJPEG stream (newest wins, reconnect), GenICam."""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from feeder.drivers.frame_source import CameraLost, CameraSizeError
from feeder.drivers.video_camera import (
    CameraError,
    CaptureOpening,
    GenICamSource,
    capture_opening,
    component_image,
    open_camera,
    prefer_grey_free_running,
    request_frame_size,
    request_genicam_size,
)
from firmware_sim.camera_http import CameraFeed, CameraHttpServer, Snapshot, free_port
from firmware_sim.camera_render import CameraModel, FrameRenderer, PartInImage

pytestmark = pytest.mark.timeout(60)


def _frames(count: int) -> list[np.ndarray]:
    return [np.full((32, 48), 40 * (k + 1), np.uint8) for k in range(count)]


def test_image_folder_in_name_order_then_end(tmp_path: Path) -> None:
    for k, image in enumerate(_frames(3)):
        cv2.imwrite(str(tmp_path / f"f{k:02d}.png"), image)
    (tmp_path / "notes.txt").write_text("not an image")
    with open_camera(str(tmp_path)) as camera:
        got = [camera.read(timeout_s=2) for _ in range(3)]
        with pytest.raises(CameraLost, match="ended"):
            camera.read(timeout_s=0.5)
    assert [f.sequence for f in got] == [0, 1, 2]
    assert [int(f.image[0, 0]) for f in got] == [40, 80, 120]


def test_video_file_keeps_every_frame(tmp_path: Path) -> None:
    path = tmp_path / "run.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 10.0, (48, 32), isColor=False)
    for image in _frames(4):
        writer.write(image)
    writer.release()
    with open_camera(str(path)) as camera:
        time.sleep(0.2)  # a slow reader loses nothing from a recording
        got = [camera.read(timeout_s=2) for _ in range(4)]
    assert [f.sequence for f in got] == [0, 1, 2, 3]
    assert [int(f.image[..., 0].mean()) for f in got] == pytest.approx([40, 80, 120, 160], abs=3)
    assert got[1].source_time_s == pytest.approx(0.1, abs=0.02)


def _server(port: int) -> CameraHttpServer:
    renderer = FrameRenderer(CameraModel(width_px=128, height_px=96), seed=0)
    start = time.monotonic()

    def snapshot() -> Snapshot:
        return Snapshot(time.monotonic() - start, [PartInImage(64, 48, 0.2, 40, 30)], {})

    return CameraHttpServer(CameraFeed(renderer, snapshot, fps=50), port=port, idle_timeout_s=1.0)


def test_live_stream_newest_frame_wins_and_reconnects() -> None:
    port = free_port()
    server = _server(port)
    camera = open_camera(f"http://127.0.0.1:{port}/video.mjpg")
    try:
        first = camera.read(timeout_s=10)
        assert first.image.shape[:2] == (96, 128)
        time.sleep(0.5)  # 25 frames come meanwhile; only the newest is kept
        newest = camera.read(timeout_s=2)
        assert newest.sequence - first.sequence > 5
        assert newest.time_s > first.time_s
        server.close()
        with pytest.raises(CameraLost):
            for _ in range(100):
                camera.read(timeout_s=0.5)
        server = _server(port)
        again = camera.read(timeout_s=15)
        assert again.sequence > newest.sequence and again.image.shape[:2] == (96, 128)
    finally:
        camera.close()
        server.close()


def test_genicam_needs_harvesters_and_a_producer(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "harvesters.core", None)
    with pytest.raises(CameraError, match=r"feeder\[genicam\]"):
        GenICamSource(tmp_path / "producer.cti")
    monkeypatch.undo()
    pytest.importorskip("harvesters.core")
    with pytest.raises(CameraError, match="no such GenTL producer"):
        open_camera(f"genicam:{tmp_path / 'missing.cti'}")


def test_bad_spec_is_a_camera_error(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="no such file"):
        open_camera(str(tmp_path / "nothing.avi"))


def test_devices_open_through_v4l2_without_ffmpeg_timeouts() -> None:
    # V4L2 (DirectShow, AVFoundation) refuse to open with the FFmpeg-only timeout parameters
    for spec in (0, "/dev/video0", "/dev/v4l/by-id/usb-cam-video-index0"):
        assert capture_opening(spec, 5.0, "linux") == CaptureOpening(cv2.CAP_V4L2, (), device=True)
    assert capture_opening(1, 5.0, "win32") == CaptureOpening(cv2.CAP_ANY, (), device=True)
    stream = capture_opening("http://127.0.0.1:8080/video.mjpg", 2.5, "linux")
    assert stream.backend == cv2.CAP_FFMPEG and not stream.device
    assert stream.params == (cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, 2500, cv2.CAP_PROP_READ_TIMEOUT_MSEC, 2500)
    assert capture_opening("run.avi", 5.0, "linux") == CaptureOpening(cv2.CAP_ANY, (), device=False)


def test_a_character_device_is_tried_as_a_camera() -> None:
    if not Path("/dev/null").is_char_device():
        pytest.skip("no /dev/null character device here")
    with pytest.raises(CameraError, match=r"^/dev/null: not a camera") as raised:
        open_camera("/dev/null")
    assert "\n" not in str(raised.value)
    with pytest.raises(CameraError, match=r"^/dev/video987: no such file"):
        open_camera("/dev/video987")


class _Capture:
    """A device that gives ``native`` frames in YUYV and the asked size only in MJPG."""

    def __init__(self, native: tuple[int, int]) -> None:
        self.props = {cv2.CAP_PROP_FRAME_WIDTH: native[0], cv2.CAP_PROP_FRAME_HEIGHT: native[1]}
        self.mjpg = False
        self.asked: dict[int, float] = {}

    def set(self, prop: int, value: float) -> bool:
        if prop == cv2.CAP_PROP_FOURCC:
            self.mjpg = value == cv2.VideoWriter.fourcc(*"MJPG")
        else:
            self.asked[prop] = value
            if self.mjpg:
                self.props[prop] = int(value)
        return True

    def get(self, prop: int) -> float:
        return float(self.props[prop])


def test_frame_size_asked_of_a_device_then_in_mjpg() -> None:
    granted = _Capture((2048, 2048))
    assert request_frame_size(granted, (2048, 2048)) == (2048, 2048) and not granted.mjpg
    capture = _Capture((640, 480))
    assert request_frame_size(capture, (2048, 1536)) == (2048, 1536) and capture.mjpg
    assert capture.asked == {cv2.CAP_PROP_FRAME_WIDTH: 2048, cv2.CAP_PROP_FRAME_HEIGHT: 1536}


def test_frames_of_another_size_than_asked_are_refused() -> None:
    port = free_port()
    server = _server(port)
    url = f"http://127.0.0.1:{port}/video.mjpg"
    try:
        with open_camera(url, size_px=(128, 96)) as camera:
            assert camera.read(timeout_s=10).image.shape[:2] == (96, 128)
        with open_camera(url, size_px=(2048, 2048)) as camera:
            # a CameraError, and a lost sensor to the pose sensor that waits for frames
            with pytest.raises(CameraSizeError, match=r"frames are 128x96 px, not the 2048x2048") as raised:
                camera.read(timeout_s=3)
            assert isinstance(raised.value, CameraError) and isinstance(raised.value, CameraLost)
            assert "\n" not in str(raised.value)
    finally:
        server.close()


def test_folder_of_another_size_than_asked_ends_with_the_sizes(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "f00.png"), _frames(1)[0])
    with (
        open_camera(str(tmp_path), size_px=(64, 32)) as camera,
        pytest.raises(CameraError, match=r"frames are 48x32 px, not the 64x32 px asked for"),
    ):
        camera.read(timeout_s=2)


class _Component:
    """What harvesters gives for a buffer's image component (the attributes the source reads)."""

    def __init__(self, pixels: np.ndarray, data_format: str) -> None:
        self.height, self.width = pixels.shape[:2]
        self.num_components_per_pixel = float(pixels.shape[2]) if pixels.ndim == 3 else 1.0
        self.data_format = data_format
        self.data = pixels.ravel()  # harvesters' data is flat


def test_genicam_components_become_grey_images() -> None:
    mono = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    image = component_image(_Component(mono, "Mono16"))
    assert image.dtype == np.uint16 and np.array_equal(image, mono)
    red = np.zeros((3, 4, 3), np.uint8)
    red[..., 0] = 255  # red in RGB8, blue in BGR8
    assert np.all(component_image(_Component(red, "RGB8")) == 76)
    assert np.all(component_image(_Component(red, "BGR8")) == 29)
    rgba = np.dstack([red, np.full((3, 4), 255, np.uint8)])
    grey = component_image(_Component(rgba, "RGBa8"))
    assert grey.shape == (3, 4) and np.all(grey == 76)
    # a colour camera's raw mosaic: demosaiced to grey, not located as a checkerboard of edges
    mosaic = np.zeros((4, 6), np.uint8)
    mosaic[0::2, 0::2] = 200  # R of an RGGB pattern: a red scene
    for name in ("BayerRG8", "BayerRG16"):
        raw = mosaic.astype(np.uint16) * 257 if name.endswith("16") else mosaic
        grey = component_image(_Component(raw, name))
        assert np.array_equal(grey, cv2.cvtColor(raw, cv2.COLOR_BayerRGGB2GRAY))
        assert np.ptp(grey[1:-1, 1:-1]) <= np.ptp(raw) / 20  # uniform, where the mosaic alternates
    rggb = component_image(_Component(mosaic, "BayerRG8"))
    assert not np.array_equal(component_image(_Component(mosaic, "BayerGB8")), rggb)  # the pattern counts
    with pytest.raises(CameraError, match="YUV422_8 is not supported"):
        component_image(_Component(np.zeros((3, 4, 2), np.uint8), "YUV422_8"))


class _Node:
    def __init__(self, value: str | int, symbolics: tuple[str, ...] = ()) -> None:
        self.value = value
        self.symbolics = symbolics


def test_genicam_camera_set_to_grey_and_free_running() -> None:
    class NodeMap:
        PixelFormat = _Node("BayerRG8", ("BayerRG8", "RGB8", "Mono8"))
        TriggerSelector = _Node("AcquisitionStart", ("AcquisitionStart", "FrameStart"))
        TriggerMode = _Node("On", ("On", "Off"))

    prefer_grey_free_running(NodeMap, (AttributeError,))
    assert NodeMap.PixelFormat.value == "Mono8"
    assert (NodeMap.TriggerSelector.value, NodeMap.TriggerMode.value) == ("FrameStart", "Off")

    class Mono12NoTrigger:  # a Mono format is kept; missing features are left alone
        PixelFormat = _Node("Mono12", ("Mono12", "Mono8"))

    prefer_grey_free_running(Mono12NoTrigger, (AttributeError,))
    assert Mono12NoTrigger.PixelFormat.value == "Mono12"


class _Side:
    """A GenICam Width or Height whose largest value shrinks as its offset grows."""

    def __init__(self, value: int, largest: int, offset: _Node) -> None:
        self._value, self.largest, self.offset = value, largest, offset

    @property
    def value(self) -> int:
        return self._value

    @value.setter
    def value(self, value: int) -> None:
        if value + int(self.offset.value) > self.largest:
            raise ValueError(f"{value} out of range with offset {self.offset.value}")
        self._value = value


def test_genicam_camera_asked_for_the_frame_size_moves_its_roi_to_0_only_if_needed() -> None:
    class NodeMap:
        OffsetX = _Node(100)
        OffsetY = _Node(8)
        Width = _Side(640, 2048, OffsetX)
        Height = _Side(480, 1536, OffsetY)

    request_genicam_size(NodeMap, (2048, 480), (AttributeError, ValueError))
    assert (NodeMap.Width.value, NodeMap.OffsetX.value) == (2048, 0)  # 2048 needed OffsetX 0
    assert (NodeMap.Height.value, NodeMap.OffsetY.value) == (480, 8)  # already so: left alone
    request_genicam_size(NodeMap, (1024, 1000), (AttributeError, ValueError))
    assert (NodeMap.Width.value, NodeMap.Height.value, NodeMap.OffsetY.value) == (1024, 1000, 8)

    class NoRoi:  # a camera without the features is left as it is
        pass

    request_genicam_size(NoRoi, (2048, 2048), (AttributeError, ValueError))


def test_a_genicam_camera_is_asked_for_the_frame_size() -> None:
    """viky's cameras start at 400 × 400 px: asked for 320 × 240, they give it (before, every
    frame was refused as of another size)."""
    genicam = pytest.importorskip("genicam")
    pytest.importorskip("harvesters.core")
    producer = Path(genicam.__file__).parent / "viky.cti"
    if not producer.is_file():
        pytest.skip("no viky.cti in the genicam package")
    with open_camera(f"genicam:{producer}", size_px=(320, 240)) as camera:
        frame = camera.read(timeout_s=20)
    assert frame.image.shape == (240, 320)


def test_a_genicam_camera_slower_than_one_fetch_gives_its_frames() -> None:
    """viky at 1 frame/s read with 0.3 s fetches (an exposure or trigger longer than a fetch):
    the timeouts are waited through; each reopened the camera before, and no frame ever came
    ("fetch failed: ", the timeout's empty message)."""
    genicam = pytest.importorskip("genicam")
    pytest.importorskip("harvesters.core")
    producer = Path(genicam.__file__).parent / "viky.cti"
    if not producer.is_file():
        pytest.skip("no viky.cti in the genicam package")

    class OneFrameASecond(GenICamSource):
        def _open(self) -> None:
            super()._open()
            self._acquirer.stop()
            self._acquirer.remote_device.node_map.AcquisitionFrameRate.value = 1.0
            self._acquirer.start()

    with OneFrameASecond(producer, fetch_timeout_s=0.3) as camera:
        frames = [camera.read(timeout_s=4) for _ in range(2)]
        assert not camera.error
    assert frames[1].sequence == frames[0].sequence + 1
    assert frames[1].time_s - frames[0].time_s == pytest.approx(1.0, abs=0.3)


def test_genicam_colour_camera_gives_grey_frames() -> None:
    genicam = pytest.importorskip("genicam")
    pytest.importorskip("harvesters.core")
    producer = Path(genicam.__file__).parent / "viky.cti"  # the genicam package's simulated cameras
    if not producer.is_file():
        pytest.skip("no viky.cti in the genicam package")
    # its cameras start in RGBa8 (4 components per pixel: reshaped as one, every frame failed)
    # and give no buffer timestamps
    with open_camera(f"genicam:{producer}") as camera:
        frame = camera.read(timeout_s=20)
    assert frame.image.ndim == 2 and frame.image.dtype == np.uint8


def test_a_stream_that_stays_down_is_logged_once_until_frames_flow(caplog: pytest.LogCaptureFixture) -> None:
    """Each retry of an unreachable stream logged "cannot open" at INFO (45 lines in 21 s during a
    camera outage); now the first, repeats at DEBUG, and again once frames have flowed."""
    caplog.set_level(logging.DEBUG, logger="feeder.drivers.frame_source")
    port = free_port()
    camera = open_camera(f"http://127.0.0.1:{port}/video.mjpg")
    try:
        deadline = time.monotonic() + 10
        while len(caplog.records) < 4 and time.monotonic() < deadline:
            time.sleep(0.1)
        levels = [r.levelno for r in caplog.records if "cannot open" in r.getMessage()]
        assert len(levels) >= 4 and levels[0] == logging.INFO
        assert set(levels[1:]) == {logging.DEBUG}, levels
        server = _server(port)
        try:
            camera.read(timeout_s=15)
            server.close()
            deadline = time.monotonic() + 10
            while (
                not any("stream lost" in r.getMessage() for r in caplog.records)
                and time.monotonic() < deadline
            ):
                time.sleep(0.1)
            lost = [r for r in caplog.records if "stream lost" in r.getMessage()]
            assert lost and lost[0].levelno == logging.INFO  # a new outage is logged again
        finally:
            server.close()
    finally:
        camera.close()
