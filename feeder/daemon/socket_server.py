"""The daemon's control interface: a Unix socket, one JSON object per line.

Owner-only (0600) in an owner-only directory (0700); a socket path or directory that another
user owns is refused, and so is a peer whose uid is not ours (SO_PEERCRED).  One JSON object
per line, at most :data:`~feeder.daemon.client.MAX_LINE_BYTES`; a longer line is answered with
an error and the connection closed; a line that is not JSON gets an error reply.  Up to
:data:`MAX_CLIENTS` clients at once, each on its own thread.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import stat
import struct
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from feeder.daemon.client import MAX_LINE_BYTES, check_owned_by_me
from feeder.errors import InputError

MAX_CLIENTS = 32
LISTEN_BACKLOG = 128
"""Connections the kernel holds before accept: bursts of short-lived clients must not find
the socket full (a client's non-blocking connect then fails at once)."""


def prepare_socket_dir(socket_path: Path) -> None:
    """Create the socket's directory 0700, or check that ours is owner-only; refuse others'."""
    directory = socket_path.parent
    with contextlib.suppress(FileExistsError):
        directory.mkdir(mode=0o700, parents=True)
    info = check_owned_by_me(directory, "socket directory")
    if not stat.S_ISDIR(info.st_mode):
        raise PermissionError(f"{directory} is not a directory")
    if info.st_mode & 0o022:
        raise PermissionError(
            f"socket directory {directory} is writable by others "
            f"(mode {oct(info.st_mode & 0o777)}); refusing it"
        )


def bind_socket(socket_path: Path) -> socket.socket:
    """A listening Unix socket at ``socket_path``, mode 0600.

    A stale socket of ours is replaced; a live one (another daemon answers) or
    any path owned by another user is refused with :class:`InputError`.
    """
    field = str(socket_path)
    if len(os.fsencode(socket_path)) >= 108:
        raise InputError(field, "socket path is longer than the 107 bytes Unix sockets allow")
    try:
        prepare_socket_dir(socket_path)
        if os.path.lexists(socket_path):
            info = check_owned_by_me(socket_path, "socket")
            if not stat.S_ISSOCK(info.st_mode):
                raise InputError(field, "exists and is not a socket; refusing to replace it")
            probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                probe.connect(str(socket_path))
            except OSError:
                socket_path.unlink()
            else:
                raise InputError(field, "another daemon is already listening there")
            finally:
                probe.close()
    except PermissionError as err:
        raise InputError(field, str(err)) from None
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    old_umask = os.umask(0o177)
    try:
        sock.bind(str(socket_path))
    finally:
        os.umask(old_umask)
    os.chmod(socket_path, 0o600)
    sock.listen(LISTEN_BACKLOG)
    return sock


def peer_uid(conn: socket.socket) -> int:
    """The connecting process' uid (Linux SO_PEERCRED)."""
    creds = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    return int(struct.unpack("3i", creds)[1])


class SocketServer:
    """Serves ``handle(request) -> reply`` on a Unix socket (:func:`bind_socket`) until
    :meth:`close`; once ``closing`` is set, clients get no further replies."""

    def __init__(
        self,
        socket_path: Path,
        handle: Callable[[Any], dict[str, Any]],
        closing: threading.Event | None = None,
    ) -> None:
        self.socket_path = socket_path
        self._handle = handle
        self._socket = bind_socket(socket_path)
        self._closing = closing or threading.Event()
        self._lock = threading.Lock()
        self._clients = 0
        threading.Thread(target=self._accept, name="accept", daemon=True).start()

    def close(self) -> None:
        """Stop accepting and remove the socket (connected clients end with their next line)."""
        self._closing.set()
        self._socket.close()
        with contextlib.suppress(FileNotFoundError):
            self.socket_path.unlink()

    def _accept(self) -> None:
        while not self._closing.is_set():
            try:
                conn, _ = self._socket.accept()
            except OSError:
                return
            with self._lock:
                full = self._clients >= MAX_CLIENTS
                if not full:
                    self._clients += 1
            if full:
                self._send(conn, {"ok": False, "error": f"too many clients (max {MAX_CLIENTS})"})
                conn.close()
                continue
            threading.Thread(target=self._serve_client, args=(conn,), name="client", daemon=True).start()

    @staticmethod
    def _send(conn: socket.socket, obj: dict[str, Any]) -> None:
        with contextlib.suppress(OSError, ValueError):
            conn.sendall(json.dumps(obj, allow_nan=False, default=str).encode() + b"\n")

    def _serve_client(self, conn: socket.socket) -> None:
        try:
            if peer_uid(conn) != os.getuid():
                self._send(conn, {"ok": False, "error": "permission denied: not the owner"})
                return
            reader = conn.makefile("rb")
            while not self._closing.is_set():
                line = reader.readline(MAX_LINE_BYTES + 1)
                if not line:
                    return
                if len(line) > MAX_LINE_BYTES or not line.endswith(b"\n"):
                    if len(line) <= MAX_LINE_BYTES:
                        return  # disconnected mid-line
                    self._send(
                        conn,
                        {
                            "ok": False,
                            "error": f"request longer than {MAX_LINE_BYTES} bytes; closing the connection",
                        },
                    )
                    return
                if not line.strip():
                    continue
                try:
                    request = json.loads(line)
                except (ValueError, RecursionError) as err:
                    # not JSON, not UTF-8, an integer past Python's digit limit, or nested
                    # deeper than the parser's recursion allows
                    self._send(
                        conn,
                        {"ok": False, "error": f"malformed request: {type(err).__name__}: {str(err)[:200]}"},
                    )
                    continue
                self._send(conn, self._safe_handle(request))
        except OSError:
            pass
        finally:
            conn.close()
            with self._lock:
                self._clients -= 1

    def _safe_handle(self, request: Any) -> dict[str, Any]:
        try:
            reply = self._handle(request)
            json.dumps(reply, allow_nan=False, default=str)
            return reply
        except (ValueError, TypeError, OverflowError, RecursionError) as err:
            # a value no handler expected (NaN in a reply, an integer too large for a float)
            return {"ok": False, "error": f"cannot answer: {type(err).__name__}: {str(err)[:200]}"}
