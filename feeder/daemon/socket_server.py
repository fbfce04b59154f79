"""The daemon's control interface: a Unix socket, one JSON object per line.

Owner-only (0600) in an owner-only directory (0700); a socket path or directory that another
user owns is refused, and so is a peer whose uid is not ours (SO_PEERCRED).  One JSON object
per line, at most :data:`~feeder.daemon.client_connection.MAX_LINE_BYTES`; a longer line is answered with
an error and the connection closed; a line that is not JSON gets an error reply.

Up to :data:`MAX_CLIENTS` clients are served in full at once, each on its own thread.  No client
can hold the socket against ``stop``:

- a request line must be complete within :data:`IDLE_TIMEOUT_S` of its first byte (a slow-loris
  guard), and a reply taken within it; a request being answered (a move waiting for its result)
  has no time limit;
- a client silent between requests keeps its slot while there is room; when every slot is taken,
  the one silent longest, if silent for :data:`IDLE_TIMEOUT_S` or more, is closed for a newcomer;
- beyond :data:`MAX_CLIENTS`, up to :data:`MAX_DOORWAY` more connections are read: ``stop`` and
  ``status`` (:data:`ALWAYS_SERVED`) are answered on them, anything else gets the one-line
  refusal and the connection is closed; each request line must arrive within
  :data:`DOORWAY_TIMEOUT_S`.  Such a connection is served in full once a slot frees;
- when the process runs out of descriptors (or memory, or threads) to accept a connection with,
  the server keeps accepting: it closes the client silent longest, if silent for
  :data:`DOORWAY_TIMEOUT_S`, so that a waiting ``stop`` gets its descriptor, and tries again
  every :data:`ACCEPT_RETRY_S` (logged once a minute at most).

A handler gets, beside the request, a ``hung_up()`` check: whether the client has closed its
connection (gone, not merely done sending) while its request is answered, so that a long
request nobody will read the reply of can stop (:func:`peer_closed`).
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import select
import socket
import stat
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from feeder.daemon.client_connection import MAX_LINE_BYTES, check_owned_by_me
from feeder.daemon.log_throttle import LogThrottle
from feeder.errors import InputError

log = logging.getLogger(__name__)

MAX_CLIENTS = 32
"""Clients served in full at once."""
MAX_DOORWAY = 32
"""Connections beyond :data:`MAX_CLIENTS` that are still read, for ``stop`` and ``status``."""
ALWAYS_SERVED = frozenset({"stop", "status"})
"""Commands answered whatever the number of clients (quick: they never wait for a move)."""
IDLE_TIMEOUT_S = 10.0
"""How long a begun request line may take to complete, and a reply to be taken; a client silent
this long gives up its slot to a newcomer when every slot is taken."""
DOORWAY_TIMEOUT_S = 2.0
"""How long a connection beyond :data:`MAX_CLIENTS` has for each request line (a client sends its
request as it connects; a waiting move's heartbeat every 0.25 s)."""
LISTEN_BACKLOG = 128
"""Connections the kernel holds before accept: bursts of short-lived clients must not find
the socket full (a client's non-blocking connect then fails at once)."""
ACCEPT_RETRY_S = 0.1
"""The wait before accepting again after an accept (or a client's thread) failed."""
OUT_OF_RESOURCES = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
"""accept()'s errors for a process or system out of descriptors or memory."""


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


def check_socket_path(socket_path: Path) -> None:
    """:class:`InputError` naming ``socket_path`` when no socket can be bound there, whatever
    runs: too long for a Unix socket, a file that is no socket, below a file.  Writes nothing
    (the daemon's start checks it before its state directory and log exist)."""
    field = str(socket_path)
    if len(os.fsencode(socket_path)) >= 108:
        raise InputError(field, "socket path is longer than the 107 bytes Unix sockets allow")
    for above in socket_path.parents:
        if os.path.lexists(above):
            if not above.is_dir():
                raise InputError(field, f"{above} is not a directory")
            break
    if os.path.lexists(socket_path) and not stat.S_ISSOCK(socket_path.lstat().st_mode):
        raise InputError(field, "exists and is not a socket; refusing to replace it")


def bind_socket(socket_path: Path) -> socket.socket:
    """A listening Unix socket at ``socket_path``, mode 0600.

    A stale socket of ours is replaced; a live one (another daemon answers) or
    any path owned by another user is refused with :class:`InputError`.
    """
    field = str(socket_path)
    check_socket_path(socket_path)
    try:
        prepare_socket_dir(socket_path)
        if os.path.lexists(socket_path):
            check_owned_by_me(socket_path, "socket")
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


def peer_closed(conn: socket.socket) -> bool:
    """Whether the peer has closed the connection (both ways: ``POLLHUP``), without reading or
    waiting.  A client that only shut down its sending side (``nc -N``, ``socat``) still reads
    its reply: that is ``POLLRDHUP`` alone, and not a close.  A socket closed here is gone too."""
    poller = select.poll()
    try:
        poller.register(conn, select.POLLHUP)
    except (ValueError, OSError):  # closed: no file descriptor
        return True
    return any(events & (select.POLLHUP | select.POLLERR | select.POLLNVAL) for _, events in poller.poll(0))


def peer_uid(conn: socket.socket) -> int:
    """The connecting process' uid (Linux SO_PEERCRED)."""
    creds = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    return int(struct.unpack("3i", creds)[1])


class _Client:
    """One connection and what the server knows of it (``full``, ``silent_since`` and
    ``evicted`` change under the server's lock)."""

    def __init__(self, conn: socket.socket) -> None:
        self.conn = conn
        self.full = False
        """Served in full (one of the :data:`MAX_CLIENTS`), else only :data:`ALWAYS_SERVED`."""
        self.silent_since: float | None = time.monotonic()
        """Since when it has sent nothing while no request of its is being answered; None otherwise."""
        self.evicted = False
        """Closed to give its slot to a newcomer."""
        self.buffer = bytearray()


def _identity(path: Path) -> tuple[int, int] | None:
    """(device, inode) of what is at ``path`` now, or None."""
    try:
        info = os.lstat(path)
    except FileNotFoundError:
        return None
    return info.st_dev, info.st_ino


class SocketServer:
    """Serves ``handle(request, hung_up) -> reply`` on a Unix socket (:func:`bind_socket`) until
    :meth:`close`; once ``closing`` is set, clients get no further replies.  The socket is bound
    at once (a second daemon is refused before it touches anything); ``serving`` False: the
    connections wait in the backlog until :meth:`serve`."""

    def __init__(
        self,
        socket_path: Path,
        handle: Callable[[Any, Callable[[], bool]], dict[str, Any]],
        closing: threading.Event | None = None,
        serving: bool = True,
    ) -> None:
        self.socket_path = socket_path
        self._handle = handle
        self._socket = bind_socket(socket_path)
        self._bound = _identity(socket_path)  # close() removes this socket only, no later one's
        self._closing = closing or threading.Event()
        self._lock = threading.Lock()
        self._full: set[_Client] = set()
        self._doorway: set[_Client] = set()
        self._accept_trouble = LogThrottle(log)
        self._acceptor = threading.Thread(target=self._accept, name="accept", daemon=True)
        if serving:
            self.serve()

    def serve(self) -> None:
        """Start accepting connections."""
        self._acceptor.start()

    def close(self) -> None:
        """Stop accepting and remove the socket (connected clients end with their next line), if
        the path still holds it: a daemon started meanwhile on a path taken from under this one
        keeps its own."""
        self._closing.set()
        # closing alone leaves the thread blocked in accept() for good (Linux wakes it on shutdown)
        with contextlib.suppress(OSError):
            self._socket.shutdown(socket.SHUT_RDWR)
        self._socket.close()
        if self._acceptor.ident is not None:
            self._acceptor.join(timeout=1.0)
        if _identity(self.socket_path) == self._bound:
            with contextlib.suppress(FileNotFoundError):
                self.socket_path.unlink()

    @staticmethod
    def _refusal() -> dict[str, Any]:
        return {"ok": False, "error": f"too many clients (max {MAX_CLIENTS})"}

    def _accept(self) -> None:
        """Accept connections until :meth:`close` (its shutdown ends the blocked accept); any
        other failure (out of descriptors, memory or threads) is waited out, never the end."""
        while not self._closing.is_set():
            try:
                conn, _ = self._socket.accept()
            except OSError as err:
                if self._closing.is_set():
                    return
                if err.errno in OUT_OF_RESOURCES:
                    with self._lock:
                        self._reclaim_slot(DOORWAY_TIMEOUT_S)
                self._accept_trouble.warning("cannot accept a control connection (%s); trying again", err)
                self._closing.wait(ACCEPT_RETRY_S)
                continue
            client = _Client(conn)
            with self._lock:
                admitted = self._take_slot(client)
                if not admitted and len(self._doorway) < MAX_DOORWAY:
                    self._doorway.add(client)
                    admitted = True
            if not admitted:
                self._send(conn, self._refusal())
                self._discard_unread(conn)
                conn.close()
                continue
            try:
                threading.Thread(
                    target=self._serve_client, args=(client,), name="client", daemon=True
                ).start()
            except RuntimeError as err:  # "can't start new thread"
                with self._lock:
                    self._full.discard(client)
                    self._doorway.discard(client)
                conn.close()
                self._accept_trouble.warning("cannot serve a control connection (%s); closed it", err)
                self._closing.wait(ACCEPT_RETRY_S)

    def _take_slot(self, client: _Client, reclaim: bool = True) -> bool:
        """Under the lock: serve ``client`` in full if a slot is free (or, with ``reclaim``, can
        be freed: :meth:`_reclaim_slot`)."""
        if client.full:
            return True
        if len(self._full) >= MAX_CLIENTS and not (reclaim and self._reclaim_slot(IDLE_TIMEOUT_S)):
            return False
        self._doorway.discard(client)
        self._full.add(client)
        client.full = True
        return True

    def _reclaim_slot(self, silent_s: float) -> bool:
        """Under the lock: close the client silent longest, if it has been silent for
        ``silent_s``, and free its slot (and its descriptor, once its thread has ended)."""
        now = time.monotonic()
        silent = [c for c in self._full if c.silent_since is not None and now - c.silent_since >= silent_s]
        if not silent:
            return False
        victim = min(silent, key=lambda c: c.silent_since or now)
        victim.evicted = True
        self._full.discard(victim)
        with contextlib.suppress(OSError):
            victim.conn.shutdown(socket.SHUT_RDWR)  # its thread's recv returns at once, and it ends
        log.info(
            "closed a client silent for %.1f s to make room for a new one", now - (victim.silent_since or now)
        )
        return True

    @staticmethod
    def _send(conn: socket.socket, obj: dict[str, Any]) -> bool:
        """Send one reply line; False when the client did not take it within :data:`IDLE_TIMEOUT_S`
        or is gone."""
        try:
            conn.settimeout(IDLE_TIMEOUT_S)
            conn.sendall(json.dumps(obj, allow_nan=False, default=str).encode() + b"\n")
        except (OSError, ValueError):
            return False
        return True

    def _read_line(self, client: _Client) -> bytes | None:
        """The client's next request line (with its newline), or None when the connection is to
        close: end of stream, evicted, a line too long or not completed in time (the last two are
        answered first)."""
        buffer = client.buffer
        begun = time.monotonic() if buffer else None  # a line sent ahead counts from now
        while True:
            end = buffer.find(b"\n")
            if 0 <= end < MAX_LINE_BYTES:
                line = bytes(buffer[: end + 1])
                del buffer[: end + 1]
                return line
            if end >= 0 or len(buffer) >= MAX_LINE_BYTES:
                self._send(
                    client.conn,
                    {
                        "ok": False,
                        "error": f"request longer than {MAX_LINE_BYTES} bytes; closing the connection",
                    },
                )
                return None
            now = time.monotonic()
            with self._lock:
                if client.evicted:
                    return None
                if buffer:
                    client.silent_since = None
                elif client.silent_since is None:
                    client.silent_since = now
                full, silent_since = client.full, client.silent_since
            limit_s = IDLE_TIMEOUT_S if full else DOORWAY_TIMEOUT_S
            if begun is not None:
                deadline: float | None = begun + limit_s
            elif full or silent_since is None:
                deadline = None  # silent between requests: kept while there is room
            else:
                deadline = silent_since + limit_s
            try:
                if deadline is not None and deadline <= now:
                    raise TimeoutError
                client.conn.settimeout(None if deadline is None else deadline - now)
                chunk = client.conn.recv(65536)
            except TimeoutError:
                if begun is None:  # a connection beyond the cap that asked nothing
                    self._send(client.conn, self._refusal())
                else:
                    self._send(
                        client.conn,
                        {
                            "ok": False,
                            "error": f"request line incomplete after {limit_s:g} s; closing the connection",
                        },
                    )
                return None
            with self._lock:
                if client.evicted or not chunk:
                    return None  # evicted, or the client closed (perhaps mid-line)
                client.silent_since = None
            if begun is None:
                begun = time.monotonic()
            buffer += chunk

    def _serve_client(self, client: _Client) -> None:
        conn = client.conn
        try:
            if peer_uid(conn) != os.getuid():
                self._send(conn, {"ok": False, "error": "permission denied: not the owner"})
                return
            while not self._closing.is_set():
                line = self._read_line(client)
                if line is None:
                    return
                if not line.strip():
                    continue
                reply: dict[str, Any] | None = None
                try:
                    request = json.loads(line)
                except (ValueError, RecursionError) as err:
                    # not JSON, not UTF-8, an integer past Python's digit limit, or nested
                    # deeper than the parser's recursion allows
                    request = None
                    reply = {
                        "ok": False,
                        "error": f"malformed request: {type(err).__name__}: {str(err)[:200]}",
                    }
                cmd = request.get("cmd") if isinstance(request, dict) else None
                always = isinstance(cmd, str) and cmd in ALWAYS_SERVED
                with self._lock:
                    full = self._take_slot(client, reclaim=not always)
                if not (full or always):
                    self._send(conn, self._refusal())
                    return
                if reply is None:
                    reply = self._safe_handle(request, lambda: peer_closed(conn))
                if not self._send(conn, reply):
                    return
        except OSError:
            pass
        finally:
            self._discard_unread(conn)
            conn.close()
            with self._lock:
                self._full.discard(client)
                self._doorway.discard(client)

    @staticmethod
    def _discard_unread(conn: socket.socket) -> None:
        """Read what the client sent beyond its last line (the rest of an over-long one): closing
        a Unix socket with unread data resets the peer's connection before it reads our last
        reply.  A few reads at most, none waiting."""
        with contextlib.suppress(OSError):  # BlockingIOError: nothing more
            conn.setblocking(False)
            for _ in range(16):
                if not conn.recv(MAX_LINE_BYTES):
                    return

    def _safe_handle(self, request: Any, hung_up: Callable[[], bool]) -> dict[str, Any]:
        try:
            reply = self._handle(request, hung_up)
            json.dumps(reply, allow_nan=False, default=str)
            return reply
        except (ValueError, TypeError, OverflowError, RecursionError) as err:
            # a value no handler expected (NaN in a reply, an integer too large for a float)
            return {"ok": False, "error": f"cannot answer: {type(err).__name__}: {str(err)[:200]}"}
        except Exception as err:  # the one boundary of a client's request
            # a handler's bug: the client gets a reply (as HTTP's 500), the traceback goes to the
            # log, and the connection, the other clients and the device stay as they were
            log.exception("request %.200r failed", request)
            return {"ok": False, "error": f"internal error ({type(err).__name__}: {str(err)[:200]}): "
                    "see the daemon's log"}  # fmt: skip
