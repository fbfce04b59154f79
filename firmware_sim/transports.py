"""Endpoints: the console on TCP or a pty, and the camera's frame stream on TCP.

Servers bind to 127.0.0.1 only.  Each console connection gets its own
:class:`~firmware_sim.console.ConsoleSession`.  The pty behaves like a real
ANC300's serial console, whose session does not end on DTR: one session (login
state, echo) from the first program that opens the pty's device path on, and a
reply the program did not read before closing it stays for the next program
(``PtyConsole(..., keep_session=False)``: a new session per open, unread
replies dropped at the hang-up, as a console that resets on DTR would).
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import termios
import threading
import time
import tty
from collections import deque
from collections.abc import Callable

from firmware_sim.console import ConsoleSession

LOCALHOST = "127.0.0.1"
MAX_CONSOLE_CLIENTS = 32
"""Logged-in console sessions at once."""
MAX_PENDING_LOGINS = 4
"""Console connections still at the password prompt; a new one evicts the one with the most
failed tries (a guesser), else the longest-waiting one not having a password checked, and is
refused only if every one is having its first password checked."""
TYPING_GRACE_S = 1.0
"""The one connection at the prompt not having a password checked is not replaced for this long
after it got the prompt: it is an operator about to type while every other place checks a
guesser's tries (a loaded server reads the line late: such an operator was evicted between the
prompt and the password).  Among several idle ones (a flood) the longest-waiting goes at once."""
LOGIN_TIMEOUT_S = 5.0
"""A connection at the password prompt that sends no password line for this long is closed."""
HANGUP_POLL_S = 0.005
MAX_SENSOR_CLIENTS = 16
SENSOR_BACKLOG_BYTES = 64 * 1024
"""A camera client more than this far behind is disconnected."""
SENSOR_SEND_TIMEOUT_S = 2.0
"""A camera client that takes no data for this long while data waits for it is disconnected."""
SENSOR_SEND_BUFFER_BYTES = 32 * 1024
POLL_S = 0.1

SessionFactory = Callable[[str], ConsoleSession]
"""Makes a console session for a connection from a source (the peer's address, or ``pty``)."""


def check_local(host: str) -> None:
    """Refuse any bind address but 127.0.0.1 / localhost."""
    if host not in (LOCALHOST, "localhost"):
        raise ValueError(f"refusing to bind {host!r}: only {LOCALHOST} is allowed")


class _Connection:
    """One console connection and its session (state read by the accept thread)."""

    def __init__(self, sock: socket.socket, session: ConsoleSession) -> None:
        self.sock = sock
        self.session = session
        self.waiting_since = time.monotonic()  # at the prompt since (connect or last try)
        self.checking = False  # a password line is being evaluated

    def typing(self) -> bool:
        """Input waits unread (a password its thread has not read yet; or the peer hung up)."""
        with contextlib.suppress(OSError, ValueError):
            return bool(select.select([self.sock], [], [], 0)[0])
        return False

    def evict(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)  # its thread's recv() returns b""


def _victim(pending: list[_Connection], now: float) -> _Connection | None:
    """The connection at the password prompt a newcomer replaces at ``now`` (monotonic s): the
    one with the most failed tries (guessers, who keep every place busy with their queued tries,
    must not keep the operator out; nor may they, reconnecting, replace an operator about to
    type, :data:`TYPING_GRACE_S`), else the longest-waiting one with no password being checked
    or waiting unread (:meth:`_Connection.typing`), else none.  One whose session logged in (its
    thread not yet at moving it to the sessions) is none of these."""
    at_prompt = [c for c in pending if not c.session.logged_in]  # one logged in is not moved yet
    failing = [c for c in at_prompt if c.session.failed_logins > 0]
    if failing:
        return max(failing, key=lambda c: (c.session.failed_logins, -c.waiting_since))
    idle = [c for c in at_prompt if not c.checking and not c.typing()]
    if len(idle) == 1 and now - idle[0].waiting_since < TYPING_GRACE_S:
        return None
    return min(idle, key=lambda c: c.waiting_since) if idle else None


class TcpConsoleServer:
    """The console on ``host:port`` (port 0 picks a free one; see :attr:`port`).

    One thread per connection.  Denial of service from the same machine is
    bounded: connections at the password prompt have their own cap
    (``max_pending``, the longest-waiting idle one makes room for a new one)
    and a login timeout, so idle connections cannot lock out an operator who
    has the password; logged-in sessions have a separate cap.  Password tries
    are paced per source by the sessions' :class:`~firmware_sim.login_throttle.LoginThrottle`.
    """

    def __init__(
        self,
        host: str,
        port: int,
        session_factory: SessionFactory,
        *,
        max_pending: int = MAX_PENDING_LOGINS,
        max_sessions: int = MAX_CONSOLE_CLIENTS,
        login_timeout_s: float = LOGIN_TIMEOUT_S,
    ) -> None:
        check_local(host)
        self._factory = session_factory
        self.max_pending = max_pending
        self.max_sessions = max_sessions
        self.login_timeout_s = login_timeout_s
        self._listener = socket.create_server((host, port), backlog=2 * (max_pending + 8))
        self.host, self.port = self._listener.getsockname()[:2]
        self._lock = threading.Lock()
        self._pending: list[_Connection] = []
        self._sessions: list[_Connection] = []
        self._thread = threading.Thread(target=self._accept, name="console-tcp", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"socket://{self.host}:{self.port}"

    def _accept(self) -> None:
        while True:
            try:
                sock, peer = self._listener.accept()
            except OSError:
                return  # closed
            conn = _Connection(sock, self._factory(str(peer[0])))
            if conn.session.logged_in:  # no password asked
                admitted = self._admit(conn, self._sessions, self.max_sessions, evict=False)
            else:
                admitted = self._admit(conn, self._pending, self.max_pending, evict=True)
            if not admitted:
                with contextlib.suppress(OSError):
                    sock.sendall(b"Too many connections\r\n")
                sock.close()
                continue
            threading.Thread(target=self._serve, args=(conn,), name="console-tcp-client", daemon=True).start()

    def _admit(self, conn: _Connection, group: list[_Connection], cap: int, evict: bool) -> bool:
        with self._lock:
            if len(group) >= cap:
                victim = _victim(group, time.monotonic()) if evict else None
                if victim is None:
                    return False
                group.remove(victim)
                victim.evict()
            group.append(conn)
            return True

    def _serve(self, conn: _Connection) -> None:
        sock, session = conn.sock, conn.session
        try:
            sock.sendall(session.greeting())
            while not session.logged_in and not session.closed:
                if not self._login_step(conn):
                    return
            if session.closed:
                return
            sock.settimeout(None)
            with self._lock:
                if conn in self._pending:
                    self._pending.remove(conn)
                full = conn not in self._sessions and len(self._sessions) >= self.max_sessions
                if not full and conn not in self._sessions:
                    self._sessions.append(conn)
            if full:
                sock.sendall(b"Too many sessions\r\n")
                return
            while not session.closed:
                data = sock.recv(4096)
                if not data:
                    break
                reply = session.feed(data)
                if reply:
                    sock.sendall(reply)
        except OSError:
            pass  # the client went away mid-line or mid-reply, or was evicted
        finally:
            with self._lock:
                for group in (self._pending, self._sessions):
                    if conn in group:
                        group.remove(conn)
            sock.close()

    def _login_step(self, conn: _Connection) -> bool:
        """Read and answer at the password prompt; False when the connection must end."""
        remaining = conn.waiting_since + self.login_timeout_s - time.monotonic()
        if remaining <= 0:
            conn.sock.sendall(b"\r\nAuthorization timeout\r\n")
            return False
        conn.sock.settimeout(remaining)
        try:
            data = conn.sock.recv(4096)
        except TimeoutError:
            return True  # the next step reports the timeout
        if not data:
            return False
        failed = conn.session.failed_logins
        conn.checking = b"\n" in data or b"\r" in data
        try:
            reply = conn.session.feed(data)
        finally:
            conn.checking = False
        if conn.session.failed_logins != failed:
            conn.waiting_since = time.monotonic()
        if reply:
            conn.sock.sendall(reply)
        return True

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._listener.shutdown(socket.SHUT_RDWR)  # wakes the accept() in its thread
        self._listener.close()
        with self._lock:
            for conn in self._pending + self._sessions:
                conn.evict()


class PtyConsole:
    """The console on a pseudo-terminal; :attr:`path` is the device to open.

    keep_session: as on a real ANC300, closing the device (the pty's hang-up,
    DTR on a serial line) ends nothing: the session (login, echo, a command
    still running) carries on, replies written before the close that the
    program did not read stay in the pty, and replies made while no program has
    it open are held and sent when one opens it.  False: a new session (and
    greeting) each time a program opens it, unread replies dropped at the close.
    """

    def __init__(self, session_factory: SessionFactory, keep_session: bool = True) -> None:
        self._factory = session_factory
        self.keep_session = keep_session
        self._master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        os.close(slave)  # nobody has it open → the master sees a hang-up
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="console-pty", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        poller = select.poll()
        poller.register(self._master, select.POLLIN)
        session: ConsoleSession | None = None
        attached = False  # a program has the device open
        held = bytearray()  # replies made while no program had it open (keep_session)
        while not self._stop.is_set():
            timeout_ms = 100 if attached else HANGUP_POLL_S * 1000
            event = dict(poller.poll(timeout_ms)).get(self._master, 0)
            hung_up = bool(event & select.POLLHUP)
            if hung_up:
                if attached and not self.keep_session:  # the program closed the pty: drop unread replies
                    self._flush_unread()
                    session = None
                attached = False
            elif not attached:  # no hang-up any more: a program opened the pty
                attached = True
                if session is None:
                    session = self._factory("pty")
                    if not session.logged_in:
                        self._write(session.greeting())
                if held and self._write(bytes(held)):
                    held.clear()
            # what the program sent before it closed the pty is still executed (keep_session)
            if event & select.POLLIN and session is not None:
                try:
                    data = os.read(self._master, 4096)
                except OSError:
                    data = b""
                    if not hung_up:
                        session, attached = None, False
                reply = session.feed(data) if session is not None and data else b""
                # feed may take long (stepw): the program may have closed the pty meanwhile
                if reply and self.keep_session and (hung_up or self._hung_up()):
                    held += reply  # written now it would be lost: the next program gets it
                elif reply and not self._write(reply):
                    session, attached = None, False
                if session is not None and session.closed:
                    session, attached = None, False
            if hung_up:
                time.sleep(HANGUP_POLL_S)

    def _flush_unread(self) -> None:
        """Drop what the program left unread (it waits on the device's side: flushing the
        master's output does not reach it) and what it sent that was not read yet."""
        with contextlib.suppress(termios.error):
            termios.tcflush(self._master, termios.TCIFLUSH)
        with contextlib.suppress(OSError, termios.error):
            fd = os.open(self.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            try:
                termios.tcflush(fd, termios.TCIFLUSH)
            finally:
                os.close(fd)

    def _hung_up(self) -> bool:
        """No program has the pty open now."""
        poller = select.poll()
        poller.register(self._master, select.POLLIN)
        return any(event & select.POLLHUP for _, event in poller.poll(0))

    def _write(self, data: bytes) -> bool:
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self._master, view) :]
        except OSError:
            return False
        return True

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        os.close(self._master)


class _Subscriber:
    """A camera client: its socket, the bytes it has not taken yet, since when it lags."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.backlog = bytearray()
        self.stalled_since: float | None = None


class LineBroadcastServer:
    """Sends every published line to every connected TCP client (the camera stream).

    :meth:`publish` only queues the line (it never blocks: the firmware's tick
    calls it); a sender thread writes to the clients without blocking.  At
    most ``max_clients`` clients (more are closed at once); a client more
    than ``SENSOR_BACKLOG_BYTES`` behind, or one that takes nothing for
    ``SENSOR_SEND_TIMEOUT_S`` while data waits for it, is disconnected.
    """

    def __init__(
        self,
        host: str,
        port: int,
        max_clients: int = MAX_SENSOR_CLIENTS,
        send_timeout_s: float = SENSOR_SEND_TIMEOUT_S,
    ) -> None:
        check_local(host)
        self.max_clients = max_clients
        self.send_timeout_s = send_timeout_s
        self._listener = socket.create_server((host, port))
        self.host, self.port = self._listener.getsockname()[:2]
        self._clients: list[_Subscriber] = []
        self._lock = threading.Lock()
        self._lines: deque[bytes] = deque(maxlen=SENSOR_BACKLOG_BYTES // 16)
        self._published = threading.Event()
        self._closed = threading.Event()
        self._threads = [
            threading.Thread(target=self._accept, name="sensor-accept", daemon=True),
            threading.Thread(target=self._send, name="sensor-send", daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    @property
    def url(self) -> str:
        return f"socket://{self.host}:{self.port}"

    @property
    def client_count(self) -> int:
        with self._lock:
            return len(self._clients)

    def publish(self, line: bytes) -> None:
        """Queue ``line`` for every client; returns at once."""
        self._lines.append(line)
        self._published.set()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self._listener.accept()
            except OSError:
                return
            with self._lock:
                full = len(self._clients) >= self.max_clients
                if not full:
                    client.setblocking(False)
                    client.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SENSOR_SEND_BUFFER_BYTES)
                    self._clients.append(_Subscriber(client))
            if full:
                client.close()

    def _send(self) -> None:
        while not self._closed.is_set():
            self._published.wait(POLL_S)
            self._published.clear()
            lines = []
            while self._lines:
                lines.append(self._lines.popleft())
            data = b"".join(lines)
            now = time.monotonic()
            with self._lock:
                for client in list(self._clients):
                    if not self._flush(client, data, now):
                        self._clients.remove(client)
                        client.sock.close()

    def _flush(self, client: _Subscriber, data: bytes, now: float) -> bool:
        """Send what ``client`` can take now; False if it must go."""
        client.backlog += data
        if len(client.backlog) > SENSOR_BACKLOG_BYTES:
            return False
        if client.backlog:
            try:
                del client.backlog[: client.sock.send(client.backlog)]
            except BlockingIOError:
                pass
            except OSError:
                return False  # the client went away
        if not client.backlog:
            client.stalled_since = None
        elif client.stalled_since is None:
            client.stalled_since = now
        return client.stalled_since is None or now - client.stalled_since <= self.send_timeout_s

    def close(self) -> None:
        self._closed.set()
        self._published.set()
        with contextlib.suppress(OSError):
            self._listener.shutdown(socket.SHUT_RDWR)  # wakes the accept() in its thread
        self._listener.close()
        for thread in self._threads:
            thread.join(timeout=1.0)
        with self._lock:
            for client in self._clients:
                client.sock.close()
            self._clients.clear()
