"""An MJPEG stream of the planar world's 2048² frames read by our HTTP reader and by FFmpeg.

Ours: :class:`feeder.drivers.http_camera.HttpCameraSource` (parts split in Python, decoded by
``cv2.imdecode``, a grey JPEG stays grey).  Baseline: the same stream through OpenCV's FFmpeg
back end (``VideoCaptureSource``, what read ``http://`` URLs before; it decodes to BGR).
Both read one pre-encoded frame served 30 times a second from a thread of this process,
so the process's CPU time per frame is the reader's (the server's is one ``sendall``).
``ratio``: FFmpeg's CPU time per frame over ours.  Also the frames each received in the window
(both should keep up with 30/s).
"""

from __future__ import annotations

import socketserver
import threading
import time

import cv2
import numpy as np

from feeder.drivers.frame_source import FrameSource
from feeder.drivers.http_camera import HttpCameraSource
from feeder.drivers.video_camera import VideoCaptureSource
from firmware_sim.camera_http import JPEG_QUALITY
from firmware_sim.camera_render import CameraModel, FrameRenderer, PartInImage

SIDE_PX = 2048
FPS = 30.0


def _stream_server(body: bytes) -> socketserver.ThreadingTCPServer:
    part = b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: %d\r\n\r\n%b\r\n" % (len(body), body)

    class Stream(socketserver.BaseRequestHandler):
        def handle(self) -> None:
            self.request.recv(65536)  # the GET
            self.request.sendall(
                b"HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary=frame\r\n\r\n"
            )
            start = time.monotonic()
            for k in range(10**6):
                try:
                    self.request.sendall(part)
                except OSError:
                    return
                time.sleep(max(0.0, start + (k + 1) / FPS - time.monotonic()))

    server = socketserver.ThreadingTCPServer(("127.0.0.1", 0), Stream)
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, args=(0.05,), daemon=True).start()
    return server


def _cpu_per_frame(camera: FrameSource, seconds: float) -> tuple[float, int]:
    """CPU seconds per frame received over ``seconds`` (after the first frame), and the frames."""
    first = camera.read(timeout_s=10).sequence
    cpu, wall = time.process_time(), time.monotonic()
    last = first
    while time.monotonic() - wall < seconds:
        last = camera.read(timeout_s=5).sequence
    frames = last - first
    return (time.process_time() - cpu) / max(frames, 1), frames


def run(quick: bool) -> dict[str, float | int]:
    renderer = FrameRenderer(CameraModel(width_px=SIDE_PX, height_px=SIDE_PX), seed=0)
    image = renderer.render([PartInImage(900, 1100, 0.3, 120, 120), PartInImage(1500, 700, 1.1, 120, 120)])
    body = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])[1].tobytes()
    server = _stream_server(body)
    url = f"http://127.0.0.1:{server.server_address[1]}/video.mjpg"
    seconds = 2.0 if quick else 6.0
    try:
        with HttpCameraSource(url) as ours:
            frame = ours.read(timeout_s=10).image
            if frame.shape != (SIDE_PX, SIDE_PX) or not np.array_equal(
                frame, cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_GRAYSCALE)
            ):
                raise AssertionError("our reader's frame is not the served JPEG decoded")
            ours_s, ours_frames = _cpu_per_frame(ours, seconds)
        with VideoCaptureSource(url) as ffmpeg:
            ffmpeg_s, ffmpeg_frames = _cpu_per_frame(ffmpeg, seconds)
    finally:
        server.shutdown()
        server.server_close()
    return {
        "ratio": ffmpeg_s / ours_s,
        "ours_cpu_ms_per_frame": ours_s * 1e3,
        "ffmpeg_cpu_ms_per_frame": ffmpeg_s * 1e3,
        "ours_frames": ours_frames,
        "ffmpeg_frames": ffmpeg_frames,
        "frames_served": int(seconds * FPS),
        "jpeg_bytes": len(body),
    }
