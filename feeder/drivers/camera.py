"""Client for a camera that streams part positions as JSON lines over TCP.

The stream (firmware_sim's ``--sensor tcp:127.0.0.1:PORT``, or any camera
process speaking the same format) is one line per frame::

    {"seq": 12, "time_s": 0.12, "position_m": 3.1e-05}

optionally with ``"poses": [[x_m, y_m, psi_rad], ...]`` (one per part, plate frame).

A reader thread keeps the newest frame; :meth:`StreamCamera.read` returns the
newest frame not yet returned (older unread frames are dropped: the position
is what matters, not the backlog).
"""

from __future__ import annotations

import contextlib
import json
import socket
import threading

from feeder.drivers.sensor import PositionSample, PositionSensor, SensorLost

MAX_LINE = 4096


def parse_url(url: str) -> tuple[str, int]:
    """``socket://HOST:PORT`` or ``HOST:PORT`` → (host, port)."""
    host, _, port = url.removeprefix("socket://").rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"expected socket://HOST:PORT, got {url!r}")
    return host, int(port)


class StreamCamera(PositionSensor):
    """Position sensor on a JSON-lines TCP stream; ``read`` raises SensorLost."""

    def __init__(self, url: str, connect_timeout_s: float = 1.0) -> None:
        self.url = url
        try:
            self._sock = socket.create_connection(parse_url(url), timeout=connect_timeout_s)
        except OSError as exc:
            raise SensorLost(f"{url}: cannot connect: {exc}") from exc
        self._sock.settimeout(None)
        self._cond = threading.Condition()
        self._latest: PositionSample | None = None
        self._returned = -1
        self._lost: str | None = None
        self._thread = threading.Thread(target=self._reader, name="camera-reader", daemon=True)
        self._thread.start()

    def _reader(self) -> None:
        buffer = b""
        reason = "stream closed"
        try:
            while True:
                data = self._sock.recv(65536)
                if not data:
                    break
                buffer += data
                *lines, buffer = buffer.split(b"\n")
                if len(buffer) > MAX_LINE:
                    reason = "line too long"
                    break
                samples = [s for s in map(_parse, lines) if s is not None]
                if samples:
                    with self._cond:
                        self._latest = samples[-1]
                        self._cond.notify_all()
        except OSError as exc:
            reason = str(exc)
        with self._cond:
            self._lost = reason
            self._cond.notify_all()

    def read(self, timeout_s: float = 1.0) -> PositionSample:
        with self._cond:
            fresh = self._cond.wait_for(
                lambda: (
                    self._lost is not None
                    or (self._latest is not None and self._latest.sequence > self._returned)
                ),
                timeout_s,
            )
            if self._lost is not None:
                raise SensorLost(f"{self.url}: {self._lost}")
            if not fresh or self._latest is None:
                raise SensorLost(f"{self.url}: no frame within {timeout_s:g} s")
            self._returned = self._latest.sequence
            return self._latest

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()


def _parse(line: bytes) -> PositionSample | None:
    try:
        frame = json.loads(line)
        poses = tuple((float(x), float(y), float(psi)) for x, y, psi in frame.get("poses", ()))
        return PositionSample(
            time_s=float(frame["time_s"]),
            position_m=float(frame["position_m"]),
            sequence=int(frame["seq"]),
            poses=poses,
        )
    except (ValueError, KeyError, TypeError, AttributeError):
        return None
