"""A camera's reported failure is the current one, cleared when frames resume (drivers/frame_source.py)."""

from __future__ import annotations

import contextlib
import threading
import time

import numpy as np
import pytest

from feeder.drivers.frame_source import CameraLost, CameraSizeError, FrameSource

pytestmark = pytest.mark.timeout(30)


class Relay(FrameSource):
    """A live camera behind a relay: refused ``refusals`` times, then frames while ``flowing`` is
    set; cleared, the relay stands still (SIGSTOP): no frame, no error, the grab just waits."""

    def __init__(
        self, refusals: int, size_px: tuple[int, int] | None = None, shape: tuple[int, int] = (8, 8)
    ) -> None:
        super().__init__("relay", max_backoff_s=0.05, size_px=size_px)
        self.refusals = refusals
        self.shape = shape
        self.flowing = threading.Event()
        self.flowing.set()
        self._start()

    def _open(self) -> None:
        if self.refusals > 0:
            self.refusals -= 1
            raise ConnectionRefusedError(111, "Connection refused")

    def _grab(self) -> tuple[np.ndarray, float | None] | None:
        while not self.flowing.wait(0.02):
            if self._closed.is_set():
                return None
        self._closed.wait(0.005)
        return np.zeros(self.shape, np.uint8), None

    def _release(self) -> None:
        pass


def stall(camera: Relay) -> None:
    """Stop ``camera``'s frames and take the last one it gave, if any."""
    camera.flowing.clear()
    time.sleep(0.1)  # a grab under way ends
    with contextlib.suppress(CameraLost):
        camera.read(timeout_s=0.05)


def test_a_stall_after_an_outage_is_not_reported_as_that_outage() -> None:
    """The old code kept the outage's reason: the stalled relay, 20 s later, read as "cannot open:
    [Errno 111] Connection refused"."""
    with Relay(refusals=3) as camera:
        frame = camera.read(timeout_s=5)  # the outage is over: frames flow
        assert frame.sequence == 0
        stall(camera)  # the relay is stopped: frames stop, nothing fails
        with pytest.raises(CameraLost) as lost:
            camera.read(timeout_s=0.3)
        assert "Connection refused" not in str(lost.value)
        assert str(lost.value) == "relay: no frame within 0.3 s (no frame)"
        assert camera.error == ""


def test_a_size_error_ends_with_frames_of_the_right_size() -> None:
    """What a reader is told follows the failure too: a stall after frames of the right size is a
    lost camera, not the earlier size error (the old code raised CameraSizeError for it)."""
    with Relay(refusals=0, size_px=(8, 8), shape=(4, 4)) as camera:
        with pytest.raises(CameraSizeError, match="frames are 4x4 px"):
            camera.read(timeout_s=0.5)
        camera.shape = (8, 8)  # the camera set up again
        camera.read(timeout_s=5)
        stall(camera)
        with pytest.raises(CameraLost) as lost:
            camera.read(timeout_s=0.3)
    assert type(lost.value) is CameraLost and "px" not in str(lost.value)
