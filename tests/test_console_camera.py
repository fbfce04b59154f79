"""The console's camera feed: frames are read and encoded only while a page watches them."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

pytest.importorskip("cv2", reason="the live camera needs OpenCV (the vision extra)")

from feeder.web.camera import CameraFeed


class Source:
    """A camera whose every read is a new 2048 × 2048 frame, counted."""

    def __init__(self) -> None:
        self.reads = 0
        self.lock = threading.Lock()

    def __call__(self) -> np.ndarray:
        with self.lock:
            self.reads += 1
        time.sleep(0.01)
        return np.full((2048, 2048), self.reads % 200, dtype=np.uint8)


def wait_until(condition, timeout_s: float = 5.0) -> bool:  # type: ignore[no-untyped-def]
    end = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > end:
            return False
        time.sleep(0.01)
    return True


def test_frames_are_encoded_only_while_a_page_watches() -> None:
    source = Source()
    feed = CameraFeed(source)
    try:
        time.sleep(0.5)
        assert source.reads == 0 and feed.jpeg is None  # nobody watches: nothing read or encoded
        with feed.watching(), feed.watching():  # two pages
            assert wait_until(lambda: feed.sequence >= 3)
            assert feed.jpeg is not None and feed.jpeg[:2] == b"\xff\xd8"  # a JPEG
            assert feed.size_px == (2048, 2048)
        seen = source.reads
        time.sleep(0.5)
        assert source.reads <= seen + 1 and feed.jpeg is None  # the last page left: it stops
        with feed.watching():  # and starts again for the next one, with a fresh frame
            assert wait_until(lambda: feed.jpeg is not None)
    finally:
        started = time.monotonic()
        feed.close()
        assert time.monotonic() - started < 1.0


class Camera(Source):
    """A camera of the console's own: opened by a read, closed by a release, both counted."""

    def __init__(self) -> None:
        super().__init__()
        self.open = True  # opened at start (a bad spec is refused then)
        self.opens = 1
        self.releases = 0

    def __call__(self) -> np.ndarray:
        if not self.open:
            self.open, self.opens = True, self.opens + 1
        return super().__call__()

    def release(self) -> None:
        self.open, self.releases = False, self.releases + 1


def test_a_camera_of_its_own_is_closed_while_no_page_watches(monkeypatch: pytest.MonkeyPatch) -> None:
    """Its reader thread decodes every frame while it is open ([http] camera)."""
    monkeypatch.setattr("feeder.web.camera.IDLE_RELEASE_S", 0.3)
    camera = Camera()
    feed = CameraFeed(camera, camera.release, camera.release)
    try:
        assert wait_until(lambda: not camera.open)  # nobody watches: closed soon after the start
        with feed.watching():
            assert wait_until(lambda: feed.jpeg is not None)
            assert camera.open and camera.opens == 2
            time.sleep(0.5)
            assert camera.open  # watched: kept open
        assert wait_until(lambda: not camera.open) and camera.releases == 2
        with feed.watching():  # the next page opens it again
            assert wait_until(lambda: feed.jpeg is not None) and camera.opens == 3
    finally:
        feed.close()
