"""Camera sources on the host: one interface over ``cv2.VideoCapture`` and GenICam (harvesters).

:func:`open_camera` takes what a user types:

- ``0``, ``1``: a USB (UVC) camera by index; ``/dev/video0``, ``/dev/v4l/by-id/...``: by device
  path (stable across reboots); both through OpenCV's V4L2 back end on Linux, opened at once;
- ``http://127.0.0.1:8080/video.mjpg``, ``rtsp://...``: a network camera (OpenCV's FFmpeg back end);
- ``run.avi``: a video file; ``frames/``: a folder of images (read in name order);
- ``genicam:/opt/producer.cti`` or ``genicam:/opt/producer.cti#SERIAL``: a GenICam camera
  through its GenTL producer (the optional ``harvesters`` package: ``pip install feeder[genicam]``),
  set to grey pixels and free running where it offers them.

With ``size_px`` a device camera (USB or GenICam) is asked for that frame size, and any source
whose frames have another size stops passing them on: :meth:`FrameSource.read` raises
:class:`CameraSizeError` (the pose sensor would place the plate origin wrongly).

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
import os
import sys
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np

from feeder.drivers.sensor import CameraError, SensorLost

# OpenCV's and FFmpeg's own warnings go to stderr beside this module's errors on every failed
# open (a camera that stays down: every reconnect); the failures come back as those errors
cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # read when its back end first opens

log = logging.getLogger(__name__)
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".pgm")


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
        self.error = ""
        self._lost: type[CameraLost] = CameraLost
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
                sequence, wrong_size = self._pass_frames(sequence)
                self._release()
                if sequence > first:
                    backoff, self._logged = 0.05, ""
                if wrong_size:
                    self._fail(wrong_size, CameraSizeError)
                elif self.live:
                    self._fail("stream lost, reconnecting")
            if not self.live or self._closed.wait(backoff):
                break
            backoff = min(2 * backoff, self.max_backoff_s)
        with self._cond:
            self._ended = True
            self._cond.notify_all()

    def _pass_frames(self, sequence: int) -> tuple[int, str]:
        """Pass the open source's frames on until it ends or fails: the next sequence number, and
        why it was left if a frame is not of ``size_px`` (else "")."""
        while not self._closed.is_set():
            try:
                grabbed = self._grab()
            except (CameraError, OSError, cv2.error) as exc:
                log.warning("camera %s: %s", self.name, exc)
                grabbed = None
            if grabbed is None:
                break
            image, source_time = grabbed
            height, width = image.shape[:2]
            if self.size_px is not None and (width, height) != self.size_px:
                asked_w, asked_h = self.size_px
                return sequence, f"frames are {width}x{height} px, not the {asked_w}x{asked_h} px asked for"
            frame = Frame(image, time.monotonic(), source_time, sequence)
            sequence += 1
            with self._cond:
                if not self.live:
                    self._cond.wait_for(lambda: self._slot is None or self._closed.is_set())
                self._slot = frame
                self._cond.notify_all()
        return sequence, ""

    def _fail(self, reason: str, lost: type[CameraLost] = CameraLost) -> None:
        """Record why the source failed; logged once (INFO) until frames flow again, then at DEBUG
        (a camera that stays down was retried, and logged, about twice a second)."""
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


@dataclass(frozen=True)
class CaptureOpening:
    """How ``cv2.VideoCapture`` opens a spec: back end, open parameters, whether it is a device."""

    backend: int
    params: tuple[int, ...]
    device: bool


def capture_opening(spec: str | int, open_timeout_s: float, platform: str = sys.platform) -> CaptureOpening:
    """A device (index, ``/dev/...``) through V4L2 on Linux and without open parameters (V4L2,
    DirectShow and AVFoundation refuse to open with FFmpeg's timeouts); a URL through FFmpeg with
    its open and read timeouts; a file through the back end OpenCV picks."""
    if isinstance(spec, int) or spec.startswith("/dev/"):
        return CaptureOpening(cv2.CAP_V4L2 if platform.startswith("linux") else cv2.CAP_ANY, (), True)
    if "://" in spec:
        timeout_ms = int(open_timeout_s * 1000)
        params = (cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, timeout_ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, timeout_ms)
        return CaptureOpening(cv2.CAP_FFMPEG, params, False)
    return CaptureOpening(cv2.CAP_ANY, (), False)


def request_frame_size(capture: Any, size_px: tuple[int, int]) -> tuple[int, int]:
    """Ask an open device for ``size_px`` frames in its pixel format, else in MJPG (what most USB
    cameras need for large frames at speed); the size it gives."""

    def ask() -> tuple[int, int]:
        capture.set(cv2.CAP_PROP_FRAME_WIDTH, size_px[0])
        capture.set(cv2.CAP_PROP_FRAME_HEIGHT, size_px[1])
        return int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))

    given = ask()
    if given != size_px:
        capture.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*"MJPG"))
        given = ask()
    return given


class VideoCaptureSource(FrameSource):
    """A camera (index or device path), stream URL or video file through ``cv2.VideoCapture``.

    A camera is opened at once (CameraError if it cannot be) and asked for ``size_px`` frames.
    """

    def __init__(
        self,
        spec: str | int,
        live: bool | None = None,
        open_timeout_s: float = 5.0,
        max_backoff_s: float = 2.0,
        size_px: tuple[int, int] | None = None,
    ) -> None:
        super().__init__(str(spec), max_backoff_s, size_px)
        self.spec = spec
        self.live = live if live is not None else not (isinstance(spec, str) and Path(spec).is_file())
        self.opening = capture_opening(spec, open_timeout_s)
        self._capture: cv2.VideoCapture | None = None
        if self.opening.device:
            self._open()
        self._start()

    def _open(self) -> None:
        if self._capture is not None:  # a device opened by __init__
            return
        capture = cv2.VideoCapture(self.spec, self.opening.backend, list(self.opening.params))
        if not capture.isOpened():
            capture.release()
            backend = cv2.videoio_registry.getBackendName(self.opening.backend)
            raise CameraError(f"{self.name}: not a camera or stream OpenCV ({backend}) can open")
        if self.opening.device:  # the newest frame, not the oldest of the driver's queue
            capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        if self.opening.device and self.size_px is not None:
            given = request_frame_size(capture, self.size_px)
            log.info("camera %s: %dx%d px asked for, %dx%d px given", self.name, *self.size_px, *given)
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

    def __init__(self, folder: Path, size_px: tuple[int, int] | None = None) -> None:
        super().__init__(str(folder), size_px=size_px)
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


BAYER_TO_GREY = {
    "BayerRG": cv2.COLOR_BayerRGGB2GRAY,
    "BayerGB": cv2.COLOR_BayerGBRG2GRAY,
    "BayerGR": cv2.COLOR_BayerGRBG2GRAY,
    "BayerBG": cv2.COLOR_BayerBGGR2GRAY,
}
"""GenICam's Bayer formats (named by their first two pixels) to OpenCV's demosaicing to grey."""


def component_image(component: Any) -> np.ndarray:
    """A GenICam image component (``data``, ``width``, ``height``, ``num_components_per_pixel``,
    ``data_format``, as harvesters gives it) as a grey image of its own (RGB/BGR converted, a
    Bayer mosaic demosaiced: located as it comes, its colour filter's checkerboard is edges)."""
    components = component.num_components_per_pixel
    if components == 1:
        plane = np.array(component.data).reshape(component.height, component.width).copy()
        bayer = BAYER_TO_GREY.get(str(component.data_format)[:7])
        return plane if bayer is None else cv2.cvtColor(plane, bayer)
    layout = str(component.data_format)[:3].upper()
    if components not in (3, 4) or layout not in ("RGB", "BGR"):
        raise CameraError(f"pixel format {component.data_format} is not supported: set Mono8 in the camera")
    image = np.array(component.data).reshape(component.height, component.width, int(components))
    codes = {
        ("RGB", 3): cv2.COLOR_RGB2GRAY,
        ("RGB", 4): cv2.COLOR_RGBA2GRAY,
        ("BGR", 3): cv2.COLOR_BGR2GRAY,
        ("BGR", 4): cv2.COLOR_BGRA2GRAY,
    }
    return cv2.cvtColor(image, codes[layout, int(components)])


def request_genicam_size(
    node_map: Any, size_px: tuple[int, int], errors: tuple[type[Exception], ...]
) -> None:
    """Ask a GenICam camera for ``size_px`` frames (``Width``, ``Height``), its offsets set to 0
    first where the size needs them (the largest size allowed shrinks as the offset grows)."""
    for offset, side, value in (("OffsetX", "Width", size_px[0]), ("OffsetY", "Height", size_px[1])):
        try:
            if int(getattr(node_map, side).value) == value:
                continue
        except errors as exc:
            log.debug("GenICam %s not readable: %s", side, exc)
            continue
        if not _set_node(node_map, side, value, errors) and _set_node(node_map, offset, 0, errors):
            _set_node(node_map, side, value, errors)


def _set_node(node_map: Any, name: str, value: str | int, errors: tuple[type[Exception], ...]) -> bool:
    """Set a GenICam feature where the camera has it and lets it be set; whether it was set."""
    try:
        getattr(node_map, name).value = value
    except errors as exc:
        log.debug("GenICam %s not set to %s: %s", name, value, exc)
        return False
    return True


def prefer_grey_free_running(node_map: Any, errors: tuple[type[Exception], ...]) -> None:
    """``PixelFormat`` Mono8 (else Mono16) unless it is Mono already, and frames not waiting for
    a trigger, where the camera offers them; ``errors``: what its node map raises for a feature
    that is missing or cannot be set."""
    try:
        current, offered = str(node_map.PixelFormat.value), tuple(node_map.PixelFormat.symbolics)
    except errors as exc:
        log.debug("GenICam PixelFormat not readable: %s", exc)
        current, offered = "", ()
    if not current.startswith("Mono"):
        for grey in ("Mono8", "Mono16"):
            if grey in offered and _set_node(node_map, "PixelFormat", grey, errors):
                break
    _set_node(node_map, "TriggerSelector", "FrameStart", errors)
    _set_node(node_map, "TriggerMode", "Off", errors)


class GenICamSource(FrameSource):
    """A GenICam camera through a GenTL producer (.cti) with ``harvesters`` (optional extra)."""

    def __init__(
        self,
        producer: Path,
        serial: str | None = None,
        fetch_timeout_s: float = 1.0,
        max_backoff_s: float = 2.0,
        size_px: tuple[int, int] | None = None,
    ) -> None:
        try:
            from genicam.genapi import GenericException as NodeException  # harvesters' dependency
            from genicam.gentl import GenericException
            from harvesters.core import Harvester
        except ImportError as exc:
            raise CameraError(
                "GenICam cameras need the optional harvesters package: pip install 'feeder[genicam]'"
            ) from exc
        if not Path(producer).is_file():
            raise CameraError(f"{producer}: no such GenTL producer (.cti) file")
        name = f"genicam:{producer}" + (f"#{serial}" if serial else "")
        super().__init__(name, max_backoff_s, size_px)
        self.fetch_timeout_s = fetch_timeout_s
        self.serial = serial
        # GenTL's own errors (timeouts, lost device, what the producer does not give)
        self._gentl_error: type[Exception] = GenericException
        # ... and a buffer of the wrong size
        self._fetch_errors: tuple[type[Exception], ...] = (GenericException, OSError, ValueError)
        # a feature the camera lacks (AttributeError) or will not take
        self._node_errors: tuple[type[Exception], ...] = (AttributeError, NodeException)
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
        node_map = self._acquirer.remote_device.node_map
        prefer_grey_free_running(node_map, self._node_errors)
        if self.size_px is not None:
            request_genicam_size(node_map, self.size_px, self._node_errors)
        self._acquirer.start()

    def _grab(self) -> tuple[np.ndarray, float | None] | None:
        if self._acquirer is None:
            return None
        try:
            with self._acquirer.fetch(timeout=self.fetch_timeout_s) as buffer:
                image = component_image(buffer.payload.components[0])
                try:
                    stamp = buffer.timestamp_ns
                except self._gentl_error:  # a producer without timestamps
                    stamp = None
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


def open_camera(spec: str, size_px: tuple[int, int] | None = None) -> FrameSource:
    """A camera from what the user typed (see the module doc); CameraError if it cannot be.

    size_px: (width, height) the frames must have (a device camera is asked for it); None: any.
    """
    if spec.startswith("genicam:"):
        producer, _, serial = spec.removeprefix("genicam:").partition("#")
        return GenICamSource(Path(producer), serial or None, size_px=size_px)
    if spec.isdigit():
        return VideoCaptureSource(int(spec), size_px=size_px)
    path = Path(spec)
    if path.is_dir():
        return ImageFolderSource(path, size_px)
    if spec.startswith("/dev/") and path.is_char_device():
        return VideoCaptureSource(spec, size_px=size_px)
    if "://" not in spec and not path.is_file():
        raise CameraError(f"{spec}: no such file, folder, camera index or URL")
    return VideoCaptureSource(spec, size_px=size_px)
