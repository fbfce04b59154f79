"""A camera's frames, as every source gives them: a reader thread fills a one-frame slot.

A reader thread per source keeps ONE frame: live sources (cameras, streams)
overwrite it, so :meth:`FrameSource.read` always returns the newest frame and
the backlog never grows (skipped frames show as gaps in ``sequence``);
recorded sources (files, folders) wait for it to be taken, so none is lost.
A live source that fails is reopened (back-off up to ``max_backoff_s``) until
closed; :meth:`FrameSource.read` raises :class:`CameraLost` while no frame
comes, naming the current failure (``error``, cleared when frames flow again: a
source that then stops without one, a stalled relay, says "no frame"). With
``size_px`` a frame of another size is not passed on: :meth:`FrameSource.read`
raises :class:`CameraSizeError` (the pose sensor would place the plate origin
wrongly).

The sources: feeder/drivers/video_camera.py (OpenCV, GenICam, recordings) and
feeder/drivers/http_camera.py (HTTP: MJPEG streams and still images).
"""

from __future__ import annotations

import logging
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from types import TracebackType

import cv2
import numpy as np

from feeder.drivers.sensor import CameraError, SensorLost

log = logging.getLogger(__name__)


class CameraLost(SensorLost):
    """No frame within the timeout: the camera is gone (reconnecting) or the recording ended."""


class CameraSizeError(CameraError, CameraLost):
    """Frames of another size than asked for: a setup error, and no frames to whoever waits for them."""


@dataclass(frozen=True)
class Frame:
    """One image (as the camera delivers it: grey or BGR, 8 or 16 bit).

    time_s: host ``time.monotonic()`` when the frame arrived.
    source_time_s: the source's own timestamp (stream/file position, camera clock), if any.
    sequence: frames delivered by the source so far, from 0 (gaps = frames skipped for newer ones).
    """

    image: np.ndarray
    time_s: float
    source_time_s: float | None
    sequence: int


class FrameSource(ABC):
    """A camera: a reader thread fills a one-frame slot (see the module doc)."""

    live = True

    def __init__(self, name: str, max_backoff_s: float = 2.0, size_px: tuple[int, int] | None = None) -> None:
        self.name = name
        self.max_backoff_s = max_backoff_s
        self.size_px = size_px
        self._cond = threading.Condition()
        self._slot: Frame | None = None
        self._returned = -1
        self._ended = False
        self._closed = threading.Event()
        self.error = ""  # why no frame comes now ("" while frames flow: cleared when they resume)
        self._lost: type[CameraLost] = CameraLost  # what read() raises meanwhile
        self._logged = ""  # the failure last logged at INFO (repeats go to DEBUG)
        self._thread = threading.Thread(target=self._run, name=f"camera-{name}", daemon=True)

    def _start(self) -> None:
        self._thread.start()

    @abstractmethod
    def _open(self) -> None:
        """Open the device; raise CameraError/OSError if it cannot be."""

    @abstractmethod
    def _grab(self) -> tuple[np.ndarray, float | None] | None:
        """The next image and its source timestamp; None at the end (recorded) or on loss (live)."""

    @abstractmethod
    def _release(self) -> None:
        """Close the device (may be called when not open)."""

    def _run(self) -> None:
        sequence, backoff = 0, 0.05
        while not self._closed.is_set():
            try:
                self._open()
            except (CameraError, OSError, cv2.error) as exc:
                self._fail(f"cannot open: {exc}")
            else:
                first = sequence
                sequence, why, lost = self._pass_frames(sequence)
                self._release()
                if sequence > first:
                    backoff, self._logged = 0.05, ""
                if self._closed.is_set():  # closed: nothing was lost
                    break
                if lost is CameraSizeError or (why and not self.live):
                    self._fail(why, lost)
                elif self.live:
                    self._fail(f"stream lost ({why}), reconnecting" if why else "stream lost, reconnecting")
            if not self.live or self._closed.wait(backoff):
                break
            backoff = min(2 * backoff, self.max_backoff_s)
        with self._cond:
            self._ended = True
            self._cond.notify_all()

    def _pass_frames(self, sequence: int) -> tuple[int, str, type[CameraLost]]:
        """Pass the open source's frames on until it ends or fails: the next sequence number, why
        it failed ("" where it ended) and what a reader is told meanwhile."""
        while not self._closed.is_set():
            try:
                grabbed = self._grab()
            except (CameraError, OSError, cv2.error) as exc:
                return sequence, str(exc) or type(exc).__name__, CameraLost
            if grabbed is None:
                break
            image, source_time = grabbed
            height, width = image.shape[:2]
            if self.size_px is not None and (width, height) != self.size_px:
                asked_w, asked_h = self.size_px
                why = f"frames are {width}x{height} px, not the {asked_w}x{asked_h} px asked for"
                return sequence, why, CameraSizeError
            frame = Frame(image, time.monotonic(), source_time, sequence)
            sequence += 1
            with self._cond:
                if not self.live:
                    self._cond.wait_for(lambda: self._slot is None or self._closed.is_set())
                self._slot = frame
                # frames flow: an earlier failure is no reason for a later wait (a camera relay
                # stopped 20 s after an outage was reported as that outage's "cannot open")
                self.error, self._lost = "", CameraLost
                self._cond.notify_all()
        return sequence, "", CameraLost

    def _fail(self, reason: str, lost: type[CameraLost] = CameraLost) -> None:
        """Record why the source failed (:attr:`error`, until frames flow again); logged once
        (INFO) until frames flow again, then at DEBUG (a camera that stays down was retried, and
        logged, about twice a second)."""
        with self._cond:
            self.error = reason
            self._lost = lost
        log.log(logging.DEBUG if reason == self._logged else logging.INFO, "camera %s: %s", self.name, reason)
        self._logged = reason

    def read(self, timeout_s: float = 1.0) -> Frame:
        """The newest frame not yet returned; CameraLost if none comes within ``timeout_s``."""
        with self._cond:
            fresh = self._cond.wait_for(
                lambda: (self._slot is not None and self._slot.sequence > self._returned) or self._ended,
                timeout_s,
            )
            if not fresh or self._slot is None or self._slot.sequence <= self._returned:
                why = self.error or ("the recording ended" if self._ended and not self.live else "no frame")
                raise self._lost(f"{self.name}: no frame within {timeout_s:g} s ({why})")
            frame = self._slot
            self._returned = frame.sequence
            if not self.live:
                self._slot = None
                self._cond.notify_all()
            return frame

    def close(self) -> None:
        self._closed.set()
        with self._cond:
            self._cond.notify_all()
        self._thread.join(timeout=5.0)

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
