"""Camera sources on the host: one interface over ``cv2.VideoCapture``, HTTP and GenICam (harvesters).

:func:`open_camera` takes what a user types:

- ``0``, ``1``: a USB (UVC) camera by index; ``/dev/video0``, ``/dev/v4l/by-id/...``: by device
  path (stable across reboots); both through OpenCV's V4L2 back end on Linux, opened at once;
- ``http://127.0.0.1:8080/video.mjpg`` (an MJPEG stream) or ``http://HOST/snapshot.jpg`` (a still
  image, fetched again for each frame): a network camera over HTTP (feeder/drivers/http_camera.py);
- ``rtsp://...`` and other URLs: a network camera through OpenCV's FFmpeg back end;
- ``run.avi``: a video file; ``frames/``: a folder of images (read in name order);
- ``genicam:/opt/producer.cti`` or ``genicam:/opt/producer.cti#SERIAL``: a GenICam camera
  through its GenTL producer (the optional ``harvesters`` package: ``pip install feeder[genicam]``),
  set to grey pixels and free running where it offers them.

With ``size_px`` a device camera (USB or GenICam) is asked for that frame size, and any source
whose frames have another size stops passing them on (feeder/drivers/frame_source.py: one
frame kept per source, the newest of a live one, reopened with back-off when it fails).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from feeder.drivers.frame_source import FrameSource
from feeder.drivers.http_camera import HttpCameraSource
from feeder.drivers.sensor import CameraError

# OpenCV's and FFmpeg's own warnings go to stderr beside this module's errors on every failed
# open (a camera that stays down: every reconnect); the failures come back as those errors
cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # read when its back end first opens

log = logging.getLogger(__name__)
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".pgm")


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
        silent_s: float = 5.0,
    ) -> None:
        try:
            from genicam.genapi import GenericException as NodeException  # harvesters' dependency
            from genicam.gentl import GenericException, TimeoutException
            from harvesters.core import Harvester
        except ImportError as exc:
            raise CameraError(
                "GenICam cameras need the optional harvesters package: pip install 'feeder[genicam]'"
            ) from exc
        if not Path(producer).is_file():
            raise CameraError(f"{producer}: no such GenTL producer (.cti) file")
        name = f"genicam:{producer}" + (f"#{serial}" if serial else "")
        super().__init__(name, max_backoff_s, size_px)
        self.fetch_timeout_s = fetch_timeout_s  # one wait for a buffer: close() waits at most this
        self.silent_s = silent_s  # no frame for this long: the camera is reopened
        self.serial = serial
        self._fetch_timeout: type[Exception] = TimeoutException
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
        """The next buffer's image and timestamp; a fetch that times out is waited through up to
        ``silent_s`` (an exposure or a trigger longer than ``fetch_timeout_s``: until 2026-11-28
        each timeout reopened the camera, which then never gave a frame)."""
        if self._acquirer is None:
            return None
        waiting_since = time.monotonic()
        while not self._closed.is_set():
            try:
                with self._acquirer.fetch(timeout=self.fetch_timeout_s) as buffer:
                    image = component_image(buffer.payload.components[0])
                    try:
                        stamp = buffer.timestamp_ns
                    except self._gentl_error:  # a producer without timestamps
                        stamp = None
                    return image, (stamp * 1e-9 if stamp else None)
            except self._fetch_timeout as exc:
                if time.monotonic() - waiting_since >= self.silent_s:
                    raise CameraError(f"no frame in {self.silent_s:g} s") from exc
            except self._fetch_errors as exc:
                raise CameraError(f"fetch failed: {exc}") from exc
        return None

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
    if spec.startswith(("http://", "https://")):
        return HttpCameraSource(spec, size_px=size_px)
    path = Path(spec)
    if path.is_dir():
        return ImageFolderSource(path, size_px)
    if spec.startswith("/dev/") and path.is_char_device():
        return VideoCaptureSource(spec, size_px=size_px)
    if "://" not in spec and not path.is_file():
        raise CameraError(f"{spec}: no such file, folder, camera index or URL")
    return VideoCaptureSource(spec, size_px=size_px)
