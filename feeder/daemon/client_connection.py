"""The daemon socket's wire, for its client: where the socket is, whose it is, and one
connection that sends a request line and reads a reply line by a deadline (a timeout leaves it
usable).  One JSON object per line each way; the server (:mod:`feeder.daemon.socket_server`)
reads request lines of at most :data:`MAX_LINE_BYTES`.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import stat
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from feeder.errors import DaemonTimeout, DaemonUnreachable

MAX_LINE_BYTES = 64 * 1024
"""Longest request line the daemon reads."""
MAX_REPLY_BYTES = 64 * MAX_LINE_BYTES
"""Longest reply line the client reads (histories and traces are long)."""


def default_socket_path() -> Path:
    """``$XDG_RUNTIME_DIR/feeder/feeder.sock``, else ``/tmp/feeder-<uid>/feeder.sock``."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    base = Path(runtime) / "feeder" if runtime else Path("/tmp") / f"feeder-{os.getuid()}"
    return base / "feeder.sock"


def check_owned_by_me(path: Path, what: str) -> os.stat_result:
    """``lstat`` of ``path``; raises :class:`PermissionError` unless the current user owns it."""
    info = path.lstat()
    if info.st_uid != os.getuid():
        raise PermissionError(
            f"{what} {path} is owned by uid {info.st_uid}, not by this user (uid {os.getuid()}); refusing it"
        )
    return info


class Connection:
    """One socket connection: send a line, read a line by a deadline (timeouts leave it usable)."""

    def __init__(self, socket_path: Path, timeout_s: float | None) -> None:
        try:
            info = check_owned_by_me(socket_path, "socket")
        except FileNotFoundError:
            raise DaemonUnreachable(
                f"no daemon socket at {socket_path} (start one with `feeder daemon`)"
            ) from None
        except PermissionError as err:
            raise DaemonUnreachable(str(err)) from None
        if not stat.S_ISSOCK(info.st_mode):
            raise DaemonUnreachable(f"{socket_path} is not a socket")
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._sock.settimeout(timeout_s)
        try:
            self._sock.connect(str(socket_path))
        except TimeoutError:
            self._sock.close()
            raise DaemonTimeout(
                f"the daemon at {socket_path} did not accept the connection within {timeout_s:g} s",
                timeout_s or 0.0,
            ) from None
        except OSError as err:
            self._sock.close()
            raise DaemonUnreachable(f"no daemon listening on {socket_path}: {err}") from None
        self._buffer = bytearray()

    def send(self, cmd: str, fields: dict[str, Any], timeout_s: float | None) -> None:
        line = json.dumps({"cmd": cmd, **fields}).encode() + b"\n"
        self._sock.settimeout(timeout_s)
        with _socket_errors(f"take the {cmd!r} request", timeout_s):
            self._sock.sendall(line)

    def receive(self, cmd: str, timeout_s: float | None) -> dict[str, Any]:
        """The next reply object; :class:`DaemonTimeout` when none is complete in ``timeout_s``."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while (end := self._buffer.find(b"\n")) < 0:
            if len(self._buffer) > MAX_REPLY_BYTES:
                raise DaemonUnreachable(f"reply to {cmd!r} longer than {MAX_REPLY_BYTES} bytes")
            remaining = None if deadline is None else deadline - time.monotonic()
            with _socket_errors(f"answer {cmd!r}", timeout_s):
                if remaining is not None and remaining <= 0:
                    raise TimeoutError
                self._sock.settimeout(remaining)
                chunk = self._sock.recv(65536)
            if not chunk:
                raise DaemonUnreachable("the daemon closed the connection")
            self._buffer += chunk
        line = bytes(self._buffer[:end])
        del self._buffer[: end + 1]
        try:
            obj = json.loads(line)
        except (json.JSONDecodeError, UnicodeDecodeError):
            obj = None
        if not isinstance(obj, dict):
            raise DaemonUnreachable(f"unexpected reply to {cmd!r}: {line[:200]!r}")
        return obj

    def close(self) -> None:
        self._sock.close()


def listening(socket_path: Path, timeout_s: float) -> bool:
    """Whether a connection to ``socket_path`` is accepted (or queued) within ``timeout_s``."""
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(timeout_s)
    try:
        probe.connect(str(socket_path))
    except (FileNotFoundError, ConnectionRefusedError):
        return False
    except OSError:  # e.g. a full backlog: somebody is still there
        return True
    finally:
        probe.close()
    return True


@contextlib.contextmanager
def _socket_errors(what: str, timeout_s: float | None) -> Iterator[None]:
    """The socket's errors as the client's: a timeout is :class:`DaemonTimeout` ("the daemon
    did not ``what`` within ``timeout_s``"), any other :class:`OSError` :class:`DaemonUnreachable`."""
    try:
        yield
    except TimeoutError:
        raise DaemonTimeout(f"the daemon did not {what} within {timeout_s:g} s", timeout_s or 0.0) from None
    except OSError as err:
        raise DaemonUnreachable(f"daemon connection failed: {err}") from None
