"""The simulated microscope camera on HTTP, the way network microscope cameras serve frames.

``GET /video.mjpg``: multipart/x-mixed-replace MJPEG (what ``cv2.VideoCapture``
reads), one JPEG per new frame; ``GET /frame.png``: the latest frame, lossless
(8-bit, or 16-bit holding 12-bit values); ``GET /truth.json``: the true poses
of that frame and its exposure time (tests only: the host's control path never
reads it).

:class:`CameraFeed` takes a snapshot of the world (exposure time, parts in the
image) at ``fps`` on its own thread and publishes each one rendered ``latency_s``
after its exposure, a pipeline: the latency does not slow the frame rate (JPEG-encoded
there, once, while an MJPEG client is connected; the PNG on the first request); the
firmware tick only ever has its pose read, so nothing here can make it wait.
:class:`CameraHttpServer` binds 127.0.0.1, serves at most ``max_clients`` connections at
once (more get 503 at once) and drops a client that reads nothing for ``idle_timeout_s``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import cv2
import numpy as np

from feeder.parts import Part
from feeder.vision.calibration import CameraCalibration
from firmware_sim.camera_render import CameraModel, FrameRenderer, PartInImage
from firmware_sim.transports import check_local
from firmware_sim.world import World

log = logging.getLogger(__name__)
BOUNDARY = "frame"
JPEG_QUALITY = 90
SEND_BUFFER_BYTES = 256 * 1024
"""A client's send buffer (the kernel doubles it): about one 2048 px frame, so a client that
falls behind skips frames instead of reading seconds-old ones (as network cameras do)."""
RENDER_SWITCH_INTERVAL_S = 0.5e-3
"""Longest wait of the render thread for the interpreter held by the tick (Python's default 5 ms,
times the ~20 hand-overs of a frame, would cost a 30 frames/s camera its rate)."""


@dataclass
class Snapshot:
    """What the camera sees at one exposure: its time (s, world clock), the parts in the
    image, and the truth to publish with it (any JSON)."""

    time_s: float
    parts: list[PartInImage]
    truth: dict[str, Any]


@dataclass
class Published:
    """One released frame with its encodings, made once on first request."""

    sequence: int
    image: np.ndarray
    truth: dict[str, Any]
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _jpeg: bytes | None = None
    _png: bytes | None = None

    def jpeg(self) -> bytes:
        with self._lock:
            if self._jpeg is None:
                image = self.image if self.image.dtype == np.uint8 else (self.image >> 4).astype(np.uint8)
                self._jpeg = _encode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            return self._jpeg

    def png(self) -> bytes:
        with self._lock:
            if self._png is None:
                self._png = _encode(".png", self.image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
            return self._png


def _encode(ext: str, image: np.ndarray, params: list[int]) -> bytes:
    ok, data = cv2.imencode(ext, image, params)
    if not ok:
        raise RuntimeError(f"cannot encode the frame as {ext}")
    return data.tobytes()


class CameraFeed:
    """Renders frames on its own thread and keeps the newest one released."""

    def __init__(
        self,
        renderer: FrameRenderer,
        snapshot: Callable[[], Snapshot],
        fps: float = 10.0,
        latency_s: float = 0.0,
    ) -> None:
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps!r}")
        self.renderer = renderer
        self.snapshot = snapshot
        self.period_s = 1.0 / fps
        self.latency_s = latency_s
        self._cond = threading.Condition()
        self._latest: Published | None = None
        self._streams = 0  # clients on /video.mjpg
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="camera-render", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        """Expose at ``fps`` and release each exposure ``latency_s`` later, a pipeline as a real
        camera's: the latency does not slow the frame rate.  A frame is rendered when released
        (the exposures in flight are snapshots); when rendering falls behind, the newest due
        exposure is released and the older ones are dropped (gaps in ``sequence``)."""
        in_flight: deque[tuple[float, int, Snapshot]] = deque()  # (release time, sequence, exposure)
        sequence = 0
        exposure = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= exposure:
                in_flight.append((now + self.latency_s, sequence, self.snapshot()))
                sequence += 1
                exposure = max(exposure + self.period_s, now)
            due = None
            while in_flight and in_flight[0][0] <= time.monotonic():
                due = in_flight.popleft()
            if due is not None:
                self._publish(due[1], due[2])
            wake = min(exposure, in_flight[0][0]) if in_flight else exposure
            self._stop.wait(max(0.0, wake - time.monotonic()))

    def _publish(self, sequence: int, shot: Snapshot) -> None:
        truth = {"sequence": sequence, "time_s": shot.time_s, **shot.truth}
        published = Published(sequence, self.renderer.render(shot.parts), truth)
        if self._streams:
            published.jpeg()  # here, once, while the frame is fresh: the clients only send it
        with self._cond:
            self._latest = published
            self._cond.notify_all()

    @contextlib.contextmanager
    def streaming(self) -> Iterator[None]:
        """While held, a client streams MJPEG: each frame is encoded on the render thread."""
        with self._cond:
            self._streams += 1
        try:
            yield
        finally:
            with self._cond:
                self._streams -= 1

    def latest(self, after: int = -1, timeout_s: float = 5.0) -> Published | None:
        """The newest frame with a sequence above ``after`` (None if none within the timeout)."""
        with self._cond:
            self._cond.wait_for(
                lambda: (self._latest is not None and self._latest.sequence > after) or self._stop.is_set(),
                timeout_s,
            )
            latest = self._latest
            return latest if latest is not None and latest.sequence > after else None

    def close(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self._thread.join(timeout=2.0)


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    protocol_version = "HTTP/1.0"

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("camera http: " + format, *args)

    def do_GET(self) -> None:
        feed = self.server.feed
        path = self.path.split("?", 1)[0]
        if path == "/video.mjpg":
            self._stream(feed)
            return
        if path not in ("/frame.png", "/truth.json"):
            self.send_error(404, "try /video.mjpg, /frame.png or /truth.json")
            return
        frame = feed.latest(timeout_s=self.server.idle_timeout_s)
        if frame is None:
            self.send_error(503, "no frame yet")
            return
        if path == "/frame.png":
            self._send(frame.png(), "image/png")
        else:
            self._send(json.dumps(frame.truth).encode(), "application/json")

    def _send(self, body: bytes, content_type: str) -> None:
        self.send_response(200)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _stream(self, feed: CameraFeed) -> None:
        self.send_response(200)
        self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={BOUNDARY}")
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        sequence = -1
        with feed.streaming(), contextlib.suppress(OSError):
            while not self.server.closing.is_set():
                frame = feed.latest(after=sequence, timeout_s=self.server.idle_timeout_s)
                if frame is None:
                    return
                sequence = frame.sequence
                body = frame.jpeg()
                self.wfile.write(
                    f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(body)}\r\n"
                    f"X-Timestamp: {frame.truth['time_s']}\r\n\r\n".encode()
                    + body
                    + b"\r\n"
                )
                self.wfile.flush()


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(
        self, address: tuple[str, int], feed: CameraFeed, max_clients: int, idle_timeout_s: float
    ) -> None:
        self.feed = feed
        self.idle_timeout_s = idle_timeout_s
        self.closing = threading.Event()
        self._slots = threading.BoundedSemaphore(max_clients)
        super().__init__(address, _Handler)

    def process_request(self, request: Any, client_address: Any) -> None:
        request.settimeout(self.idle_timeout_s)
        # a slow reader gets the newest frame, not a backlog: at most ~a frame in the send buffer
        request.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
        if not self._slots.acquire(blocking=False):
            with contextlib.suppress(OSError):
                request.sendall(b"HTTP/1.0 503 Service Unavailable\r\nContent-Length: 0\r\n\r\n")
            self.shutdown_request(request)
            return
        super().process_request(request, client_address)

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()


class CameraHttpServer:
    """The camera's HTTP endpoint on 127.0.0.1 (see the module doc)."""

    def __init__(
        self,
        feed: CameraFeed,
        host: str = "127.0.0.1",
        port: int = 0,
        max_clients: int = 4,
        idle_timeout_s: float = 5.0,
    ) -> None:
        check_local(host)
        self.feed = feed
        self._server = _Server((host, port), feed, max_clients, idle_timeout_s)
        self._thread = threading.Thread(
            target=self._server.serve_forever, kwargs={"poll_interval": 0.1}, name="camera-http", daemon=True
        )
        self._thread.start()

    @property
    def url(self) -> str:
        host, port = self._server.server_address[:2]
        return f"http://{host!s}:{port}"

    def close(self) -> None:
        self._server.closing.set()
        self._server.shutdown()
        self._server.server_close()
        self.feed.close()
        self._thread.join(timeout=2.0)


def serve_world_camera(
    world: World,
    port: int,
    fps: float = 10.0,
    pixel_size_m: float = 1e-6,
    latency_s: float = 0.0,
    camera: CameraModel | None = None,
    rotation_rad: float = 0.0,
    mirrored: bool = False,
) -> CameraHttpServer:
    """The world's camera on http://127.0.0.1:PORT: the plate origin at the image centre, plate
    axes turned by ``rotation_rad`` (and mirrored) in the image, the world's part
    (``world.config.part``) at its true poses, each frame released ``latency_s`` after its exposure."""
    camera = camera or CameraModel()
    # the render thread waits for the interpreter between its OpenCV calls: at most this long
    sys.setswitchinterval(min(sys.getswitchinterval(), RENDER_SWITCH_INTERVAL_S))
    calibration = CameraCalibration(
        pixel_size_m,
        rotation_rad,
        mirrored,
        origin_x_px=(camera.width_px - 1) / 2,
        origin_y_px=(camera.height_px - 1) / 2,
    )
    part = Part.parse(world.config.part)
    length_px, width_px = part.length_m / pixel_size_m, part.width_m / pixel_size_m

    def snapshot() -> Snapshot:
        time_s, poses = world.time_s, world.part_poses()
        parts, truth = [], []
        for x_m, y_m, psi in poses:
            x_px, y_px = calibration.to_image(x_m, y_m)
            angle = calibration.angle_to_image(psi)
            parts.append(PartInImage(x_px, y_px, angle, length_px, width_px))
            truth.append(
                {
                    "x_m": x_m,
                    "y_m": y_m,
                    "psi_rad": psi,
                    "x_px": x_px,
                    "y_px": y_px,
                    "angle_rad": angle,
                    "length_px": length_px,
                    "width_px": width_px,
                }
            )
        return Snapshot(
            time_s,
            parts,
            {
                "parts": truth,
                "calibration": calibration.to_dict(),
                "width": camera.width_px,
                "height": camera.height_px,
            },
        )

    return CameraHttpServer(
        CameraFeed(FrameRenderer(camera, seed=world.config.seed), snapshot, fps, latency_s), port=port
    )


def free_port() -> int:
    """A TCP port free on 127.0.0.1 just now (for tests)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
