"""A network camera over HTTP: an MJPEG stream, or a still image fetched again for each frame.

An MJPEG stream (``multipart/x-mixed-replace``: what IP and microscope cameras, mjpg-streamer,
ustreamer, motion and firmware_sim serve) is read here part by part, not through FFmpeg.
FFmpeg's MJPEG demuxer refuses every part not labelled exactly ``Content-Type: image/jpeg``
(``image/jpg``, or no type at all, which cameras also send) and OpenCV silences its reason, so
such a camera opened and then gave no frame, reconnecting for ever. Here a part is whatever
lies between two boundary lines: its ``Content-Length`` when it gives one, else up to the next
boundary; its type is not checked, its bytes are decoded by OpenCV (JPEG, PNG, ...), and one
that cannot be decoded is an error naming its size and type.

A URL that serves an image (``image/*``: a camera's snapshot URL) is fetched again for each
frame, at most :data:`STILL_RATE_HZ` times a second.  A response without a ``Content-Type`` is
taken for a stream if its body starts with ``--``, else for an image; a stream whose first
boundary line is not the declared one is split at its own (FFmpeg took any line of dashes).
A part header that does not parse is ignored (an ``X-Timestamp`` with a decimal comma; a
``Content-Length`` of -1: the part then runs to the next boundary), as FFmpeg ignored them.

Credentials in the URL (``http://user:password@host/...``) are sent by HTTP basic or digest
authentication, as the camera asks (urllib's digest: MD5 and SHA-1; a camera asking only for
another is refused by name); the source's name (in logs and errors) hides the password.
Proxies from the environment are not used: a lab camera is reached directly.  An ``https://``
camera's certificate is not checked, as FFmpeg did not: a lab camera's is self-signed.
"""

from __future__ import annotations

import http.client
import logging
import math
import ssl
import time
import urllib.error
import urllib.request
from email.message import Message
from typing import Any
from urllib.parse import SplitResult, unquote, urlsplit, urlunsplit

import cv2
import numpy as np

from feeder.drivers.frame_source import FrameSource
from feeder.drivers.sensor import CameraError

log = logging.getLogger(__name__)

MAX_HEADER_LINE = 8192
"""Bytes: a longer header line is not a header (a stream gone wrong)."""
MAX_IMAGE_BYTES = 64 * 2**20
"""Bytes: a larger part or image is not a frame."""
STILL_RATE_HZ = 30.0
"""Most fetches a second of a still-image URL (a camera answering at once is not hammered)."""
_BODY_LINE = 65536  # bytes of a body taken at once while looking for a boundary line
_BLOCK = 65536  # bytes asked of the response at once
_JPEG_START = b"\xff\xd8"


def shown_url(parts: SplitResult) -> str:
    """The URL as logs and errors show it: the password, if any, replaced by ``***``."""
    if parts.password is None:
        return urlunsplit(parts)
    host = parts.netloc.rpartition("@")[2]
    return urlunsplit(parts._replace(netloc=f"{parts.username}:***@{host}"))


def decode_image(data: bytes, content_type: str) -> np.ndarray:
    """An image from its encoded bytes (grey stays grey, colour is BGR, 16 bits stay 16)."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_ANYCOLOR | cv2.IMREAD_ANYDEPTH)
    if image is None:
        stated = content_type or "no stated type"
        raise CameraError(f"{len(data)} bytes of {stated} that OpenCV cannot decode")
    return image


def _opener(url: str, user: str | None, password: str | None) -> urllib.request.OpenerDirector:
    unchecked = ssl.create_default_context()
    unchecked.check_hostname, unchecked.verify_mode = False, ssl.CERT_NONE
    handlers: list[urllib.request.BaseHandler] = [
        urllib.request.ProxyHandler({}),
        urllib.request.HTTPSHandler(context=unchecked),
    ]
    if user is not None:
        manager = urllib.request.HTTPPasswordMgrWithDefaultRealm()
        manager.add_password(None, url, unquote(user), unquote(password or ""))
        handlers += [
            urllib.request.HTTPDigestAuthHandler(manager),
            _BasicAuthAnyRealm(manager),
        ]
    return urllib.request.build_opener(*handlers)


class _BasicAuthAnyRealm(urllib.request.HTTPBasicAuthHandler):
    """urllib's basic authentication, also answering a challenge that names no realm
    (``WWW-Authenticate: Basic``: RFC 7617 asks for one, some small servers leave it out, and
    urllib then sent nothing, the camera's 401 read as a refused password)."""

    def http_error_401(self, req: Any, fp: Any, code: int, msg: str, headers: http.client.HTTPMessage) -> Any:
        answer = super().http_error_401(req, fp, code, msg, headers)
        challenges = headers.get_all("WWW-Authenticate") or []
        if answer is None and any(challenge.strip().lower() == "basic" for challenge in challenges):
            return self.retry_http_basic_auth(req.full_url, req, "")  # any realm: the URL's user
        return answer


class _Buffered:
    """A response's bytes read in blocks (``read1``: as they come, chunked or not), for lines,
    exact lengths and the search for the next boundary; ``readline`` on the response itself
    costs several Python calls a line, and a JPEG has a line break every ~256 bytes."""

    def __init__(self, response: Any) -> None:
        self._response = response
        self._buffer = bytearray()

    def _fill(self) -> bool:
        data = self._response.read1(_BLOCK)
        self._buffer += data
        return bool(data)

    def _take(self, size: int) -> bytes:
        data = bytes(self._buffer[:size])
        del self._buffer[:size]
        return data

    def readline(self, limit: int) -> bytes:
        """A line with its end, at most ``limit`` bytes (b"" at the end of the stream)."""
        searched = 0
        while True:
            end = self._buffer.find(b"\n", searched, limit)
            if end >= 0:
                return self._take(end + 1)
            if len(self._buffer) >= limit:
                return self._take(limit)
            searched = len(self._buffer)
            if not self._fill():
                return self._take(len(self._buffer))

    def read(self, size: int) -> bytes:
        """``size`` bytes, fewer at the end of the stream."""
        while len(self._buffer) < size and self._fill():
            pass
        return self._take(size)

    def read_to_boundary(self, token: bytes, largest: int) -> bytes | None:
        """The bytes before the next line of two or more dashes and ``token``, that line consumed
        up to the token; None at the end of the stream."""
        searched = 0
        while True:
            at = self._buffer.find(token, searched)
            if at >= 0:
                end = self._buffer.find(b"\n", at)
                if end < 0 and self._fill():  # the rest of the line, to see that it ends there
                    continue
                start = self._buffer.rfind(b"\n", 0, at) + 1
                dashes = self._buffer[start:at]
                tail = self._buffer[at + len(token) : end if end >= 0 else len(self._buffer)]
                if start > 0 and len(dashes) >= 2 and not dashes.strip(b"-") and not tail.strip(b"- \t\r"):
                    body = self._take(start)
                    del self._buffer[: at + len(token) - start]
                    return body
                searched = at + 1
                continue
            if len(self._buffer) > largest:
                raise CameraError(f"a part of over {largest} bytes without a boundary")
            searched = max(searched, len(self._buffer) - len(token) + 1)
            if not self._fill():
                return None


class HttpCameraSource(FrameSource):
    """A live camera at an ``http://`` or ``https://`` URL (see the module doc).

    timeout_s: for connecting and for each read (a camera silent that long is reopened).
    """

    def __init__(
        self,
        url: str,
        timeout_s: float = 5.0,
        max_backoff_s: float = 2.0,
        size_px: tuple[int, int] | None = None,
    ) -> None:
        parts = urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise CameraError(f"{shown_url(parts)}: not an http:// or https:// URL with a host")
        super().__init__(shown_url(parts), max_backoff_s, size_px)
        self.url = urlunsplit(parts._replace(netloc=parts.netloc.rpartition("@")[2]))
        self.timeout_s = timeout_s
        self._credentials = parts.username is not None
        self._opener = _opener(self.url, parts.username, parts.password)
        self._response: Any = None  # urllib's response (an http.client.HTTPResponse)
        self._stream = _Buffered(None)  # a stream's response, read through
        self._boundary: bytes | None = None  # a stream's boundary ("" if it names none); None: an image
        self._at_headers = False  # a part's body was read up to the next boundary line
        self._first_part = True
        self._fetched = -math.inf  # time.monotonic() of the last still image's request
        self._start()

    def _request(self) -> Any:
        """The camera's response, its type checked; CameraError saying what is wrong."""
        try:
            response = self._opener.open(self.url, timeout=self.timeout_s)
        except urllib.error.HTTPError as exc:
            exc.close()
            hint = ""
            if exc.code == 401:
                hint = (
                    ": the user name or password in the URL is refused"
                    if self._credentials
                    else ": give them in the URL (http://user:password@host/...)"
                )
            raise CameraError(f"HTTP {exc.code} {exc.reason}{hint}") from exc
        except urllib.error.URLError as exc:
            raise CameraError(str(exc.reason)) from exc
        except http.client.HTTPException as exc:
            raise CameraError(f"not an HTTP answer: {exc!r}") from exc
        except ValueError as exc:  # urllib's auth handlers: a scheme or digest algorithm it lacks
            raise CameraError(f"cannot log in: {exc}") from exc
        headers: Message = response.headers
        content_type = headers.get_content_type()
        if headers.get("Content-Type") is None:  # what the body starts with tells
            content_type = "multipart/x-mixed-replace" if response.peek(2)[:2] == b"--" else "image/*"
        if content_type.startswith("multipart/"):
            boundary = headers.get_param("boundary")  # quotes removed; some name it with its "--"
            self._boundary = boundary.strip().strip("-").encode() if isinstance(boundary, str) else b""
        elif content_type.startswith("image/"):
            self._boundary = None
        else:
            response.close()
            raise CameraError(
                f"serves {content_type}: neither an MJPEG stream (multipart/x-mixed-replace) nor an image"
            )
        self._at_headers = False
        self._first_part = True  # a declared boundary the parts do not use is replaced by theirs
        return response

    def _open(self) -> None:
        self._response = self._request()
        self._stream = _Buffered(self._response)

    def _grab(self) -> tuple[np.ndarray, float | None] | None:
        try:
            if self._response is None:  # a still image: fetched again
                pause = self._fetched + 1.0 / STILL_RATE_HZ - time.monotonic()
                if pause > 0:
                    time.sleep(pause)
                self._fetched = time.monotonic()
                self._response = self._request()
            if self._boundary is None:
                body, content_type, stamp = self._image(), self._response.headers.get_content_type(), None
                self._release()
            else:
                part = self._next_part(self._stream)
                if part is None:
                    return None
                body, content_type, stamp = part
        except http.client.HTTPException as exc:  # a broken chunk or connection mid-read
            raise CameraError(f"stream broken: {exc!r}") from exc
        return decode_image(body, content_type), stamp

    def _image(self) -> bytes:
        body: bytes = self._response.read(MAX_IMAGE_BYTES + 1)
        if len(body) > MAX_IMAGE_BYTES:
            raise CameraError(f"an image of over {MAX_IMAGE_BYTES} bytes")
        return body

    def _is_boundary(self, line: bytes) -> bool:
        """A boundary line: ``--`` and the boundary (the closing one ends in ``--`` too); with no
        boundary named, any short line that starts with ``--``."""
        text = line.strip()
        if not text.startswith(b"--"):
            return False
        return text.strip(b"-") == self._boundary if self._boundary else len(text) <= 72

    def _next_part(self, stream: _Buffered) -> tuple[bytes, str, float | None] | None:
        """The next part's body, type and ``X-Timestamp`` (s); None where the stream ends."""
        if not self._at_headers:  # skip to a boundary line (the preamble, the last body's CRLF)
            skipped = 0
            while not self._is_boundary(line := stream.readline(MAX_HEADER_LINE)):
                if not line:
                    return None
                text = line.strip()
                if self._first_part and text.startswith(b"--") and 2 < len(text) <= 72:
                    self._boundary = text.strip(b"-")  # the parts' own, as FFmpeg takes any
                    log.info("camera %s: its parts are delimited by %r, not as declared", self.name, text)
                    break
                skipped += len(line)
                if skipped > MAX_IMAGE_BYTES:
                    boundary = (self._boundary or b"").decode("latin-1")
                    raise CameraError(f"no boundary line --{boundary} in {MAX_IMAGE_BYTES} bytes")
        self._at_headers = False
        self._first_part = False
        length, content_type, stamp, first = None, "", None, b""
        while (line := stream.readline(MAX_HEADER_LINE)) not in (b"\r\n", b"\n"):
            if not line:
                return None
            if line.startswith(_JPEG_START):  # a body without headers
                first = line
                break
            name, _, value = line.decode("latin-1").partition(":")
            name = name.strip().lower()
            if name == "content-length":
                length = _header_number(value, int)
                if length is not None and not 0 <= length <= MAX_IMAGE_BYTES:
                    length = None  # read to the next boundary, as FFmpeg does
            elif name == "content-type":
                content_type = value.strip()
            elif name == "x-timestamp":
                stamp = _header_number(value, float)
        if length is not None and not first:
            body: bytes | None = stream.read(length)
            return (body, content_type, stamp) if body is not None and len(body) == length else None
        if self._boundary:  # the body runs to the next boundary line
            body = stream.read_to_boundary(self._boundary, MAX_IMAGE_BYTES)
            if body is None:
                return None
            stream.readline(MAX_HEADER_LINE)  # the rest of the boundary line
            self._at_headers = True
            return (first + body).removesuffix(b"\n").removesuffix(b"\r"), content_type, stamp
        chunks = [first]
        size = len(first)
        while not self._is_boundary(line := stream.readline(_BODY_LINE)):
            if not line:
                return None
            chunks.append(line)
            size += len(line)
            if size > MAX_IMAGE_BYTES:
                raise CameraError(f"a part of over {MAX_IMAGE_BYTES} bytes without a boundary")
        self._at_headers = True
        body = b"".join(chunks)
        return body.removesuffix(b"\n").removesuffix(b"\r"), content_type, stamp

    def _release(self) -> None:
        if self._response is not None:
            self._response.close()
            self._response = None


def _header_number(value: str, kind: type[Any]) -> Any:
    """A part header's number (Content-Length, X-Timestamp); None if it is not one."""
    try:
        number = kind(value.strip())
    except ValueError:
        log.debug("part header %r ignored: not a number", value.strip()[:40])
        return None
    return number if math.isfinite(number) else None
