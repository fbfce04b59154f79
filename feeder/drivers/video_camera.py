"""Camera sources on the host: one interface over ``cv2.VideoCapture`` and GenICam (harvesters).

:func:`open_camera` takes what a user types:

- ``0``, ``1``: a USB/V4L2 camera by index;
- ``http://127.0.0.1:8080/video.mjpg``, ``rtsp://...``: a network camera (OpenCV's FFmpeg back end);
- ``run.avi``: a video file; ``frames/``: a folder of images (read in name order);
- ``genicam:/opt/producer.cti`` or ``genicam:/opt/producer.cti#SERIAL``: a GenICam camera
  through its GenTL producer (the optional ``harvesters`` package: ``pip install feeder[genicam]``).

A reader thread per source keeps ONE frame: live sources (cameras, streams)
overwrite it, so :meth:`FrameSource.read` always returns the newest frame and
the backlog never grows (skipped frames show as gaps in ``sequence``);
recorded sources (files, folders) wait for it to be taken, so none is lost.
A live source that fails is reopened (back-off up to ``max_backoff_s``) until
closed; :meth:`FrameSource.read` raises :class:`CameraLost` while no frame
comes.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np

from feeder.drivers.sensor import SensorLost
from feeder.errors import FeederError

log = logging.getLogger(__name__)
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".pgm")


class CameraError(FeederError, RuntimeError):
    """A camera cannot be opened as asked (bad spec, missing optional package)."""


class CameraLost(SensorLost):
    """No frame within the timeout: the camera is gone (reconnecting) or the recording ended."""


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

    def __init__(self, name: str, max_backoff_s: float = 2.0) -> None:
        self.name = name
        self.max_backoff_s = max_backoff_s
        self._cond = threading.Condition()
        self._slot: Frame | None = None
        self._returned = -1
        self._ended = False
        self._closed = threading.Event()
        self.error = ""
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
                if not self.live or self._closed.wait(backoff):
                    break
                backoff = min(2 * backoff, self.max_backoff_s)
                continue
            backoff = 0.05
            while not self._closed.is_set():
                try:
                    grabbed = self._grab()
                except (CameraError, OSError, cv2.error) as exc:
                    log.warning("camera %s: %s", self.name, exc)
                    grabbed = None
                if grabbed is None:
                    break
                image, source_time = grabbed
                frame = Frame(image, time.monotonic(), source_time, sequence)
                sequence += 1
                with self._cond:
                    if not self.live:
                        self._cond.wait_for(lambda: self._slot is None or self._closed.is_set())
                    self._slot = frame
                    self._cond.notify_all()
            self._release()
            if not self.live:
                break
            self._fail("stream lost, reconnecting")
        with self._cond:
            self._ended = True
            self._cond.notify_all()

    def _fail(self, reason: str) -> None:
        with self._cond:
            self.error = reason
        log.info("camera %s: %s", self.name, reason)

    def read(self, timeout_s: float = 1.0) -> Frame:
        """The newest frame not yet returned; CameraLost if none comes within ``timeout_s``."""
        with self._cond:
            fresh = self._cond.wait_for(
                lambda: (self._slot is not None and self._slot.sequence > self._returned) or self._ended,
                timeout_s,
            )
            if not fresh or self._slot is None or self._slot.sequence <= self._returned:
                why = "the recording ended" if self._ended and not self.live else self.error or "no frame"
                raise CameraLost(f"{self.name}: no frame within {timeout_s:g} s ({why})")
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


class VideoCaptureSource(FrameSource):
    """A camera index, stream URL or video file through ``cv2.VideoCapture``."""

    def __init__(
        self,
        spec: str | int,
        live: bool | None = None,
        open_timeout_s: float = 5.0,
        max_backoff_s: float = 2.0,
    ) -> None:
        super().__init__(str(spec), max_backoff_s)
        self.spec = spec
        self.live = live if live is not None else not (isinstance(spec, str) and Path(spec).is_file())
        self.open_timeout_s = open_timeout_s
        self._capture: cv2.VideoCapture | None = None
        self._start()

    def _open(self) -> None:
        params = [
            cv2.CAP_PROP_OPEN_TIMEOUT_MSEC,
            int(self.open_timeout_s * 1000),
            cv2.CAP_PROP_READ_TIMEOUT_MSEC,
            int(self.open_timeout_s * 1000),
        ]
        capture = cv2.VideoCapture(self.spec, cv2.CAP_ANY, params)
        if not capture.isOpened():
            capture.release()
            raise CameraError(f"cv2.VideoCapture cannot open {self.spec!r}")
        self._capture = capture

    def _grab(self) -> tuple[np.ndarray, float | None] | None:
        if self._capture is None:
            return None
        ok, image = self._capture.read()
        if not ok or image is None:
            return None
        position_ms = self._capture.get(cv2.CAP_PROP_POS_MSEC)
        return image, (position_ms / 1000.0 if position_ms > 0 else None)

    def _release(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None


class ImageFolderSource(FrameSource):
    """The images of a folder, in name order (a recorded source: none is skipped)."""

    live = False

    def __init__(self, folder: Path) -> None:
        super().__init__(str(folder))
        self.files = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise CameraError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)})")
        self._next = 0
        self._start()

    def _open(self) -> None:
        self._next = 0

    def _grab(self) -> tuple[np.ndarray, float | None] | None:
        if self._next >= len(self.files):
            return None
        path = self.files[self._next]
        self._next += 1
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise CameraError(f"{path}: not an image OpenCV can read")
        return image, None

    def _release(self) -> None:
        pass


class GenICamSource(FrameSource):
    """A GenICam camera through a GenTL producer (.cti) with ``harvesters`` (optional extra)."""

    def __init__(
        self,
        producer: Path,
        serial: str | None = None,
        fetch_timeout_s: float = 1.0,
        max_backoff_s: float = 2.0,
    ) -> None:
        try:
            from genicam.gentl import GenericException  # harvesters' own dependency
            from harvesters.core import Harvester
        except ImportError as exc:
            raise CameraError(
                "GenICam cameras need the optional harvesters package: pip install 'feeder[genicam]'"
            ) from exc
        if not Path(producer).is_file():
            raise CameraError(f"{producer}: no such GenTL producer (.cti) file")
        super().__init__(f"genicam:{producer}" + (f"#{serial}" if serial else ""), max_backoff_s)
        self.fetch_timeout_s = fetch_timeout_s
        self.serial = serial
        # GenTL's own errors (timeouts, lost device) and a buffer of the wrong size
        self._fetch_errors: tuple[type[Exception], ...] = (GenericException, OSError, ValueError)
        self._harvester = Harvester()
        self._harvester.add_file(str(producer))
        self._acquirer: Any = None
        self._start()

    def _open(self) -> None:
        self._harvester.update()
        key: Any = {"serial_number": self.serial} if self.serial else 0
        try:
            self._acquirer = self._harvester.create(key)
        except (ValueError, IndexError) as exc:
            raise CameraError(f"no GenICam camera {key!r}: {exc}") from exc
        self._acquirer.start()

    def _grab(self) -> tuple[np.ndarray, float | None] | None:
        if self._acquirer is None:
            return None
        try:
            with self._acquirer.fetch(timeout=self.fetch_timeout_s) as buffer:
                component = buffer.payload.components[0]
                image = np.array(component.data).reshape(component.height, component.width).copy()
                stamp = getattr(buffer, "timestamp_ns", None)
        except self._fetch_errors as exc:
            raise CameraError(f"fetch failed: {exc}") from exc
        return image, (stamp * 1e-9 if stamp else None)

    def _release(self) -> None:
        if self._acquirer is not None:
            with contextlib.suppress(Exception):
                self._acquirer.stop()
                self._acquirer.destroy()
            self._acquirer = None

    def close(self) -> None:
        super().close()
        with contextlib.suppress(Exception):
            self._harvester.reset()


def open_camera(spec: str) -> FrameSource:
    """A camera from what the user typed (see the module doc); CameraError if it cannot be."""
    if spec.startswith("genicam:"):
        producer, _, serial = spec.removeprefix("genicam:").partition("#")
        return GenICamSource(Path(producer), serial or None)
    if spec.isdigit():
        return VideoCaptureSource(int(spec))
    path = Path(spec)
    if path.is_dir():
        return ImageFolderSource(path)
    if "://" not in spec and not path.is_file():
        raise CameraError(f"{spec}: no such file, folder, camera index or URL")
    return VideoCaptureSource(spec)
