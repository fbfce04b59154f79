"""Host camera sources: folders, video files, a live MJPEG stream (newest wins, reconnect), GenICam."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from feeder.drivers.video_camera import CameraError, CameraLost, GenICamSource, open_camera
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
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (48, 32), isColor=False)
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
