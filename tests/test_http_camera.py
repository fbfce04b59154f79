"""Network cameras over HTTP as real ones serve them: MJPEG parts labelled ``image/jpg`` or not
at all, without lengths, PNG parts, still-image URLs, passwords, and pages that are no camera."""

from __future__ import annotations

import base64
import hashlib
import logging
import shutil
import ssl
import subprocess
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import cv2
import numpy as np
import pytest

from feeder.drivers.frame_source import CameraLost
from feeder.drivers.http_camera import HttpCameraSource
from feeder.drivers.sensor import CameraError
from feeder.drivers.video_camera import open_camera

pytestmark = pytest.mark.timeout(60)

Part = Callable[[int], bytes]
"""The bytes a server sends for its k-th frame (a whole multipart part or a whole image)."""


def frame(k: int) -> np.ndarray:
    """Frame k: a grey gradient whose brightness tells k."""
    image = np.tile(np.arange(64, dtype=np.uint8), (48, 1))
    return np.clip(image + 20 * (k % 8), 0, 255).astype(np.uint8)


def jpeg(k: int) -> bytes:
    return bytes(cv2.imencode(".jpg", frame(k), [cv2.IMWRITE_JPEG_QUALITY, 95])[1])


class Camera(BaseHTTPRequestHandler):
    """One server's behaviour: the response's type, each frame's bytes, an optional password."""

    content_type = "multipart/x-mixed-replace; boundary=frame"
    part: Part = staticmethod(lambda k: b"")
    stream = True
    password: str | None = None  # the user "lab"'s, asked for by ``scheme``
    scheme = "Basic"
    realm: str | None = "camera"  # None: a challenge naming no realm
    algorithm = ""  # a digest challenge's, when not left to the default (MD5)
    chunked = False  # HTTP/1.1 chunked transfer (Flask on Werkzeug or gunicorn)
    requests = 0

    def do_GET(self) -> None:
        type(self).requests += 1
        if self.password is not None and not self.authorised(self.headers.get("Authorization", "")):
            self.send_response(401)
            digest = f', qop="auth", nonce="{NONCE}"' if self.scheme == "Digest" else ""
            digest += f", algorithm={self.algorithm}" if self.algorithm else ""
            challenge = (f'realm="{self.realm}"' if self.realm is not None else "") + digest
            self.send_header("WWW-Authenticate", f"{self.scheme} {challenge}".strip())
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        self.send_response(200)
        if self.content_type:
            self.send_header("Content-Type", self.content_type)
        if not self.stream:
            body = self.part(type(self).requests)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return
        if self.chunked:
            self.send_header("Transfer-Encoding", "chunked")
        self.end_headers()
        try:
            for k in range(10_000):
                data = self.part(k)
                self.wfile.write(b"%x\r\n%b\r\n" % (len(data), data) if self.chunked else data)
                self.wfile.flush()
                time.sleep(0.01)
        except OSError:  # the client went (over TLS: an SSLError)
            pass

    def authorised(self, given: str) -> bool:
        """RFC 7617 basic or RFC 7616 digest (MD5, qop auth) credentials of "lab"."""
        if self.scheme == "Basic":
            return given == "Basic " + base64.b64encode(f"lab:{self.password}".encode()).decode()
        if not given.startswith("Digest "):
            return False
        fields = urllib.request.parse_keqv_list(urllib.request.parse_http_list(given.removeprefix("Digest ")))
        ha1, ha2 = md5(f"lab:camera:{self.password}"), md5(f"GET:{fields.get('uri')}")
        answer = md5(f"{ha1}:{NONCE}:{fields.get('nc')}:{fields.get('cnonce')}:auth:{ha2}")
        return fields.get("username") == "lab" and fields.get("response") == answer

    def log_message(self, format: str, *args: object) -> None:
        pass


NONCE = "dcd98b7102dd2f0e8b11d0f600bfb0c093"


def md5(text: str) -> str:
    return hashlib.md5(text.encode()).hexdigest()


@contextmanager
def camera_server(
    tls: ssl.SSLContext | None = None, **behaviour: object
) -> Iterator[tuple[str, type[Camera]]]:
    """A camera at http://127.0.0.1:PORT/video (https:// with ``tls``) with that behaviour (class
    attributes of Camera)."""
    attributes = {k: staticmethod(v) if k == "part" else v for k, v in behaviour.items()}
    handler = type("ThisCamera", (Camera,), attributes)
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    server.daemon_threads = True
    if tls is not None:
        server.socket = tls.wrap_socket(server.socket, server_side=True)
    thread = threading.Thread(target=server.serve_forever, args=(0.05,), daemon=True)
    thread.start()
    try:
        yield f"{'https' if tls else 'http'}://127.0.0.1:{server.server_address[1]}/video", handler
    finally:
        server.shutdown()
        server.server_close()


def read_frames(url: str, count: int, **options: object) -> list[np.ndarray]:
    with open_camera(url, **options) as camera:  # type: ignore[arg-type]
        return [camera.read(timeout_s=10).image for _ in range(count)]


def brightness(image: np.ndarray) -> int:
    """k % 8 of the frame it shows (see ``frame``)."""
    return round((float(image.mean()) - 31.5) / 20)


def test_parts_labelled_image_jpg_are_frames() -> None:
    """FFmpeg's MJPEG demuxer refuses a part not labelled exactly image/jpeg: such a camera
    opened and gave no frame, reconnecting for ever."""

    def part(k: int) -> bytes:
        body = jpeg(k)
        return b"--frame\r\nContent-Type: image/jpg\r\nContent-Length: %d\r\n\r\n%b\r\n" % (len(body), body)

    with camera_server(part=part) as (url, _):
        images = read_frames(url, 3)
    assert all(image.shape == (48, 64) and image.dtype == np.uint8 for image in images)
    assert np.abs(images[0].astype(int) - frame(brightness(images[0]))).max() <= 3


def test_parts_without_type_or_length_and_a_boundary_named_with_its_dashes() -> None:
    def part(k: int) -> bytes:
        return b"----myboundary\r\n\r\n" + jpeg(k) + b"\r\n"

    named = 'multipart/x-mixed-replace;boundary="--myboundary"'
    with camera_server(content_type=named, part=part) as (url, _):
        images = read_frames(url, 4)
    shown = [brightness(image) for image in images]
    assert all(0 <= k < 8 for k in shown) and len(set(shown)) > 1  # frames that change, decoded whole
    for image, k in zip(images, shown, strict=True):
        assert np.abs(image.astype(int) - frame(k)).max() <= 3


def test_a_stream_of_16_bit_png_parts_keeps_its_depth_and_the_camera_timestamps() -> None:
    def part(k: int) -> bytes:
        body = bytes(cv2.imencode(".png", frame(k).astype(np.uint16) * 257)[1])
        return b"--frame\r\nContent-Type: image/png\r\nX-Timestamp: %d.250\r\n\r\n%b\r\n" % (k, body)

    with camera_server(part=part) as (url, _), open_camera(url) as camera:
        first = camera.read(timeout_s=10)
    assert first.image.dtype == np.uint16
    assert np.array_equal(first.image, frame(brightness(first.image // 257)).astype(np.uint16) * 257)
    assert first.source_time_s is not None and first.source_time_s % 1 == pytest.approx(0.25)


def test_a_still_image_url_is_fetched_again_for_each_frame() -> None:
    with (
        camera_server(content_type="image/jpeg", stream=False, part=jpeg) as (url, server),
        open_camera(url) as camera,
    ):
        frames = [camera.read(timeout_s=10) for _ in range(3)]
        assert server.requests >= 3
    assert frames[0].sequence < frames[1].sequence < frames[2].sequence
    assert len({brightness(f.image) for f in frames}) > 1  # new images, not the first one again


@pytest.mark.parametrize(("scheme", "realm"), [("Basic", "camera"), ("Basic", None), ("Digest", "camera")])
def test_a_password_is_sent_as_the_camera_asks_and_never_shown(scheme: str, realm: str | None) -> None:
    """IP cameras mostly ask for digest authentication, small servers for basic, some of them
    naming no realm (urllib alone then sent nothing, and the password read as refused)."""

    def part(k: int) -> bytes:
        body = jpeg(k)
        return b"--frame\r\nContent-Type: image/jpeg\r\n\r\n%b\r\n" % body

    with camera_server(part=part, password="s3cret", scheme=scheme, realm=realm) as (url, _):
        address = url.removeprefix("http://")
        assert read_frames(f"http://lab:s3cret@{address}", 1)[0].shape == (48, 64)
        with open_camera(url) as camera, pytest.raises(CameraLost, match=r"HTTP 401.*give them in the URL"):
            camera.read(timeout_s=1)
        with open_camera(f"http://lab:wrong@{address}") as camera:
            assert camera.name == f"http://lab:***@{address}"
            with pytest.raises(CameraLost, match=r"HTTP 401.*refused") as refused:
                camera.read(timeout_s=1)
        assert "wrong" not in str(refused.value)


def test_a_page_that_is_no_camera_and_a_part_that_is_no_image_are_named(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="feeder.drivers.frame_source")
    page = camera_server(content_type="text/html", part=lambda k: b"<html></html>")
    not_a_camera = pytest.raises(CameraLost, match=r"serves text/html: neither an MJPEG stream")
    with page as (url, _), open_camera(url) as camera, not_a_camera:
        camera.read(timeout_s=1)

    def part(k: int) -> bytes:
        body = b"not an image at all" if k == 2 else jpeg(k)
        return b"--frame\r\nContent-Type: image/jpeg\r\n\r\n%b\r\n" % body

    with camera_server(part=part) as (url, server), open_camera(url) as camera:
        # each connection's third part is garbage: it costs a reconnect, frames come again
        deadline = time.monotonic() + 10
        while server.requests < 3 and time.monotonic() < deadline:
            camera.read(timeout_s=5)
        assert server.requests >= 3
        lost = "stream lost (19 bytes of image/jpeg that OpenCV cannot decode), reconnecting"
        assert any(r.getMessage().endswith(lost) for r in caplog.records)  # said, then cleared by frames


def test_urls_that_are_not_http_cameras() -> None:
    with pytest.raises(CameraError, match="not an http:// or https:// URL with a host"):
        HttpCameraSource("http:///video")


def plain_part(k: int, headers: bytes = b"Content-Type: image/jpeg\r\n") -> bytes:
    return b"--frame\r\n" + headers + b"\r\n" + jpeg(k) + b"\r\n"


def test_part_headers_that_do_not_parse_are_ignored_as_ffmpeg_did() -> None:
    """A C# server's X-Timestamp with a decimal comma, a Content-Length of -1: each made every
    part an error (0 frames, reconnecting for ever)."""
    quirky = b"Content-Type: image/jpeg\r\nContent-Length: -1\r\nX-Timestamp: 12,50000\r\n"
    with camera_server(part=lambda k: plain_part(k, quirky)) as (url, _), open_camera(url) as camera:
        frames = [camera.read(timeout_s=10) for _ in range(3)]
    assert all(f.image.shape == (48, 64) and f.source_time_s is None for f in frames)


def test_a_response_without_a_content_type_is_read_by_what_it_starts_with() -> None:
    with camera_server(content_type="", part=plain_part) as (url, _):
        assert len(read_frames(url, 3)) == 3
    with camera_server(content_type="", stream=False, part=jpeg) as (url, _):
        assert read_frames(url, 2)[1].shape == (48, 64)


def test_a_digest_algorithm_urllib_lacks_is_refused_by_name_and_the_reader_lives_on() -> None:
    """SHA-256 digest (Hikvision-OEM firmware) made urllib raise ValueError: the reader thread
    died, never reconnected, and read() said only "no frame"."""
    sha256 = camera_server(part=plain_part, password="s3cret", scheme="Digest", algorithm="SHA-256")
    with sha256 as (url, _), open_camera(url.replace("://", "://lab:s3cret@")) as camera:
        for _ in range(2):  # still trying: the same reason each time
            with pytest.raises(CameraLost, match=r"cannot log in: .*SHA-256"):
                camera.read(timeout_s=1)
        assert camera._thread.is_alive()


def test_a_still_image_url_is_not_fetched_faster_than_30_times_a_second() -> None:
    """Fetched back to back, a camera answering at once took 600 requests a second."""
    still = camera_server(content_type="image/jpeg", stream=False, part=jpeg)
    with still as (url, server), open_camera(url) as camera:
        camera.read(timeout_s=10)
        first, start = server.requests, time.monotonic()
        time.sleep(1.0)
        rate = (server.requests - first) / (time.monotonic() - start)
    assert 10 < rate <= 32


def test_a_self_signed_https_camera_is_read_as_ffmpeg_read_it(tmp_path: Path) -> None:
    if shutil.which("openssl") is None:
        pytest.skip("no openssl command to make a self-signed certificate")
    key, cert = tmp_path / "key.pem", tmp_path / "cert.pem"
    command = ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1"]
    command += ["-subj", "/CN=camera", "-keyout", str(key), "-out", str(cert)]
    subprocess.run(command, check=True, capture_output=True, timeout=60)
    tls = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    tls.load_cert_chain(cert, key)
    with camera_server(tls, part=plain_part) as (url, _):
        assert url.startswith("https://") and read_frames(url, 2)[1].shape == (48, 64)


def test_a_chunked_stream_without_lengths_is_split_at_its_boundary_lines_only() -> None:
    """Flask's MJPEG (no part lengths, chunked over HTTP/1.1) was split line by line: ~30 ms of
    CPU for a 1.2 MB frame.  Lines in a body that only look like boundaries are kept."""
    comment = b"\r\n--frame-not-a-boundary\r\n--frameX\r\n----\r\n"

    def part(k: int) -> bytes:
        body = jpeg(k)  # a JPEG comment segment (FF FE) after its start: decoders skip it
        body = body[:2] + b"\xff\xfe" + (len(comment) + 2).to_bytes(2, "big") + comment + body[2:]
        return b"--frame\r\nContent-Type: image/jpeg\r\n\r\n" + body + b"\r\n"

    with camera_server(part=part, chunked=True, protocol_version="HTTP/1.1") as (url, _):
        images = read_frames(url, 4)
    for image in images:
        assert np.abs(image.astype(int) - frame(brightness(image))).max() <= 3


def test_a_stream_delimited_otherwise_than_declared_is_split_at_its_own_boundary() -> None:
    """Declared boundary=frame, parts delimited by --myboundary: no frame and no reason, for ever
    (FFmpeg takes any line of dashes)."""

    def part(k: int) -> bytes:
        body = jpeg(k)
        return b"--myboundary\r\nContent-Length: %d\r\n\r\n%b\r\n" % (len(body), body)

    with camera_server(part=part) as (url, _):
        assert len(read_frames(url, 3)) == 3
