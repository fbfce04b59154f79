"""The live view's camera: the newest image, scaled down and JPEG-encoded on its own thread."""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from feeder.errors import InputError

log = logging.getLogger(__name__)

CAMERA_PERIOD_S = 1 / 60
"""The live view asks the camera for a new frame this often; it encodes each new frame once
(at most the camera's rate: 15 frames/s from the simulator)."""
CAMERA_MAX_SIDE_PX = 640
"""The live view's frames are the camera's shrunk by the smallest whole factor that fits this."""
JPEG_QUALITY = 80
UNWATCHED_CHECK_S = 0.25
"""With no page watching, the feed reads and encodes nothing; it looks this often for close.
(Encoding every frame regardless cost the daemon ~75 % of a core: 38 % → 113 % with
``--http`` and no browser, the simulator's 2048 px frames at 15 frames/s.)"""

ImageSource = Callable[[], Any]
"""Returns the newest camera image (numpy, grey or BGR) or None; may block up to ~1 s."""
IDLE_RELEASE_S = 5.0
"""A camera of its own (``[http] camera``) is closed after no page watched it this long, and
opened again for the next page: its reader thread decodes every frame while open."""


class CameraFeed:
    """Reads the newest camera image on its own thread and keeps it JPEG-encoded, while a page
    watches it (:meth:`watching`)."""

    def __init__(
        self,
        source: ImageSource,
        close_source: Callable[[], None] = lambda: None,
        release_source: Callable[[], None] | None = None,
    ) -> None:
        """``release_source``: called on the feed's thread once no page watched for
        :data:`IDLE_RELEASE_S` (the source opens itself again on its next read)."""
        import cv2  # OpenCV (the optional vision extra): only with a camera

        self._cv2 = cv2
        self.source = source
        self._close_source = close_source
        self._release_source = release_source
        self.jpeg: bytes | None = None
        self.size_px = (0, 0)
        """(width, height) of the camera's image before it was scaled down for the page."""
        self.sequence = 0
        self._watchers = 0
        self._watched = threading.Event()
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="console-camera", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        cv2 = self._cv2
        began = -math.inf
        last: Any = None
        held = True  # the source may be open (a configured camera is opened at start)
        while not self._closed.wait(max(0.0, began + CAMERA_PERIOD_S - time.monotonic())):
            if not self._watched.wait(UNWATCHED_CHECK_S) or self._closed.is_set():
                if held and self._release_source is not None and time.monotonic() - began > IDLE_RELEASE_S:
                    self._release_source()
                    held = False
                continue
            began = time.monotonic()
            held = True
            try:
                image = self.source()
            except (OSError, RuntimeError) as err:  # CameraLost (a SensorLost), a closed link
                log.debug("console camera: %s", err)
                continue
            if image is None or image is last:  # no new frame since the last one sent
                continue
            last = image
            size_px = (int(image.shape[1]), int(image.shape[0]))
            factor = math.ceil(max(size_px) / CAMERA_MAX_SIDE_PX)
            if factor > 1:  # by a whole factor: OpenCV's fast area average (2048 px → 512: 8 ms, not 25)
                image = cv2.resize(
                    image, (size_px[0] // factor, size_px[1] // factor), interpolation=cv2.INTER_AREA
                )
            if image.dtype != "uint8":
                image = cv2.convertScaleAbs(image, alpha=255.0 / max(1, int(image.max())))
            ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            with self._lock:
                if ok and self._watchers:  # not after the last page left during the encoding
                    self.jpeg, self.size_px = data.tobytes(), size_px
                    self.sequence += 1

    @contextlib.contextmanager
    def watching(self) -> Iterator[None]:
        """While a page shows the live view: the feed reads and encodes frames only then."""
        with self._lock:
            self._watchers += 1
            self._watched.set()
        try:
            yield
        finally:
            with self._lock:
                self._watchers -= 1
                if not self._watchers:
                    self._watched.clear()
                    self.jpeg = None  # a page that comes later gets a fresh frame, not this one

    def close(self) -> None:
        self._closed.set()
        self._thread.join(timeout=2.0)
        self._close_source()


def camera_feed(spec: str | None, daemon: Any) -> CameraFeed | None:
    """The live view's camera: ``spec`` (an :func:`~feeder.drivers.video_camera.open_camera`
    spec: a URL, device index, folder), else the daemon's ``latest_image()`` where it has one
    (a camera pose sensor), else none: the page draws the plate from the poses alone."""
    try:
        if spec is not None:
            from feeder.drivers.video_camera import CameraError, open_camera

            try:
                frames = open_camera(spec)
            except CameraError as err:
                raise InputError("http.camera", str(err)) from None
            camera = _OpenWhileWatched(spec, frames)
            return CameraFeed(camera.image, camera.release, camera.release)
        latest = getattr(daemon, "latest_image", None)
        if callable(latest):
            return CameraFeed(lambda: _image(latest()))
    except ImportError as err:
        raise InputError(
            "http.camera", f"the live camera needs OpenCV ({err}): pip install feeder[vision]"
        ) from None
    return None


class _OpenWhileWatched:
    """A camera of the console's own: open while pages watch it (see :data:`IDLE_RELEASE_S`)."""

    def __init__(self, spec: str, frames: Any) -> None:
        self.spec = spec
        self.frames: Any = frames  # opened at start: a bad spec is refused then

    def image(self) -> Any:
        if self.frames is None:
            from feeder.drivers.video_camera import open_camera

            self.frames = open_camera(self.spec)
        return self.frames.read(1.0).image

    def release(self) -> None:
        if self.frames is not None:
            self.frames.close()
            self.frames = None


def _image(latest: Any) -> Any:
    """The image of what ``latest_image()`` returned: an image, (image, detections), or None."""
    return latest[0] if isinstance(latest, tuple) else latest
