"""Client of the daemon's Unix socket: one JSON object per line each way.

Requests are ``{"cmd": "move" | "stop" | "status" | "calibrate" | "history" |
"shutdown", ...}``; replies are ``{"ok": true, ...}`` or ``{"ok": false,
"error": "..."}``.  The client refuses a socket that another user owns, so a
planted socket cannot impersonate the daemon.
"""

from __future__ import annotations

import json
import os
import socket
import stat
from pathlib import Path
from typing import Any

MAX_LINE_BYTES = 64 * 1024


class DaemonUnavailable(RuntimeError):
    """No daemon answers on the socket (not running, wrong path, wrong owner)."""


def check_owned_by_me(path: Path, what: str) -> os.stat_result:
    """``lstat`` of ``path``; raises :class:`PermissionError` unless the current user owns it."""
    info = path.lstat()
    if info.st_uid != os.getuid():
        raise PermissionError(f"{what} {path} is owned by uid {info.st_uid}, not by this user "
                              f"(uid {os.getuid()}); refusing it")
    return info


class Client:
    """A connection to the daemon at ``socket_path``."""

    def __init__(self, socket_path: Path, timeout_s: float = 10.0) -> None:
        self.socket_path = Path(socket_path)
        try:
            info = check_owned_by_me(self.socket_path, "socket")
        except FileNotFoundError:
            raise DaemonUnavailable(f"no daemon socket at {self.socket_path} "
                                    "(start one with `feeder daemon`)") from None
        except PermissionError as err:
            raise DaemonUnavailable(str(err)) from None
        if not stat.S_ISSOCK(info.st_mode):
            raise DaemonUnavailable(f"{self.socket_path} is not a socket")
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._sock.settimeout(timeout_s)
        try:
            self._sock.connect(str(self.socket_path))
        except OSError as err:
            self._sock.close()
            raise DaemonUnavailable(f"no daemon listening on {self.socket_path}: {err}") from None
        self._file = self._sock.makefile("rb")

    def request(self, cmd: str, timeout_s: float | None = None, **fields: Any) -> dict[str, Any]:
        """Send one request and return the reply object (``ok`` tells success)."""
        line = json.dumps({"cmd": cmd, **fields}).encode() + b"\n"
        self._sock.settimeout(timeout_s)
        try:
            self._sock.sendall(line)
            reply = self._file.readline(MAX_LINE_BYTES * 64)
        except OSError as err:
            raise DaemonUnavailable(f"daemon connection failed: {err}") from None
        if not reply:
            raise DaemonUnavailable("the daemon closed the connection")
        obj = json.loads(reply)
        if not isinstance(obj, dict):
            raise DaemonUnavailable(f"unexpected reply: {reply[:200]!r}")
        return obj

    def close(self) -> None:
        self._file.close()
        self._sock.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
