"""One connection to an ANC300-compatible console (attocube ANC300, firmware_sim): :class:`Anc300Link`.

The link is pyserial's ``serial_for_url``, so one driver speaks to a device
path (``/dev/ttyUSB0``, a pty), ``socket://HOST:7230`` (the ANC300's TCP
console) or ``rfc2217://HOST:PORT`` (a serial port behind a network server).
Protocol: docs/anc300-protocol.md.  The axes behind it: :mod:`feeder.drivers.anc300`.

A lock (one command at a time, so any number of threads may share it), a timeout per
reply, login when the device asks for a password (the TCP console always greets and
asks; a serial port may stay silent), an identity check (``ver``), ``echo off``, and
recovery that does not rely on the unit dropping anything: a real ANC300's serial
console keeps its session and every unread reply when the port is closed (no reset on
DTR), so a late reply would answer the next command.  Any timeout, broken reply or I/O
error raises :class:`~feeder.drivers.amplifier.AmplifierLinkLost` (a timeout:
:class:`ReplyTimeout`); an I/O error (or a timeout on a network console) closes the
port.  The next command first resynchronises: it drains what arrives until the line is
quiet, sends ``ver`` and discards everything up to the reply that starts ``attocube
ANC300`` and its ``OK``, then ``echo off`` (a second ``ver`` reply before its ``OK`` is a
stale one, skipped too), and after a lost reply sends ``stop`` to every axis on the link
before the command.  Serial ports are opened exclusively (another program using
pyserial's lock cannot interleave).
"""

from __future__ import annotations

import contextlib
import logging
import math
import re
import threading
import time
from collections.abc import Callable

import serial
from serial.urlhandler.protocol_socket import Serial as SocketSerial

from feeder.drivers.amplifier import (
    AmplifierError,
    AmplifierLinkLost,
)
from feeder.protocol.anc300 import DEFAULT_PASSWORD

DEFAULT_BAUDRATE = 38400
"""The ANC300's serial console rate (ignored over USB CDC-ACM; RS-232 and USB adapters need it)."""
GREETING_QUIET_S = 0.1
"""A serial console silent this long (from connecting, or after its last byte) asks for no password
(a serial port may send nothing; the TCP console always greets and asks)."""
RESYNC_QUIET_S = 0.15
"""Resynchronising after a lost reply first reads until the line has been silent this long, s
(the late replies of commands that timed out arrive and are discarded) ..."""
RESYNC_DRAIN_MAX_S = 1.0
"""... for at most this long, s (a line that never goes quiet is resynchronised on anyway)."""
IDENTITY = "attocube ANC300"
"""The first line of an ANC300's ``ver`` reply starts with this (what qcodes' driver checks too);
it is also the mark the link resynchronises on."""
SHOWN_CHARS = 200
"""At most this much of what a wrong device answered goes into the error."""
_VALUE = re.compile(r"^(\w+) = (\S+)(?: (\S+))?$")

LINK_ERRORS: tuple[type[BaseException], ...] = (serial.SerialException, OSError)
"""What a broken port raises (plus termios.error on POSIX: tcflush on a dead pty)."""
try:
    import termios

    LINK_ERRORS += (termios.error,)
except ImportError:  # pragma: no cover - not POSIX
    pass
QUERY_ERRORS: tuple[type[BaseException], ...] = (*LINK_ERRORS, AmplifierLinkLost)


class ReplyTimeout(AmplifierLinkLost):
    """No complete reply within the timeout, the link not known broken (a ``stepw`` on a burst
    that plays longer than asked); a closed or failing link raises :class:`AmplifierLinkLost`."""


log = logging.getLogger(__name__)


class _GreetingSocket(SocketSerial):
    """pyserial's ``socket://`` port, except that opening it discards nothing: pyserial flushes
    the input as it opens, which swallows the greeting of a console on a near host."""

    _opening = False

    def open(self) -> None:
        self._opening = True
        try:
            super().open()
        finally:
            self._opening = False

    def reset_input_buffer(self) -> None:
        if not self._opening:
            super().reset_input_buffer()


class Anc300Link:
    """One serial/TCP connection to an ANC300-compatible console (thread-safe).

    url: anything ``serial.serial_for_url`` opens; timeout_s: longest wait for
    a complete reply (and, on ``socket://``, for the greeting); password: sent
    when the device asks for it; baudrate: of a serial port (bit/s).
    """

    def __init__(
        self,
        url: str,
        password: str = DEFAULT_PASSWORD,
        timeout_s: float = 1.0,
        baudrate: int = DEFAULT_BAUDRATE,
    ) -> None:
        self.url = url
        self.password = password
        self.timeout_s = timeout_s
        self.baudrate = baudrate
        self.lock = threading.Lock()
        self.version: list[str] = []  # the unit's ``ver`` reply, once identified
        self._port: serial.SerialBase | None = None
        self._in_sync = False  # False: the next command resynchronises first
        self._stop_pending = False  # a reply was lost: stop every attached axis after resyncing
        self._axes: dict[int, list[Callable[[], None]]] = {}
        self._shortest_s = math.inf  # the shortest round trip of this connection's commands
        self._closed = False  # close() was called: no command reopens the port

    # -- public ---------------------------------------------------------------

    def query(self, command: str, timeout_s: float | None = None) -> list[str]:
        """Send one command line; return its data lines.

        Raises :class:`AmplifierError` on an ``ERROR`` reply (message = the
        device's error line) or when the device is no ANC300, and
        :class:`AmplifierLinkLost` when no complete reply came within the
        timeout (:class:`ReplyTimeout`) or the link broke; the next query then
        resynchronises (and reconnects, if the port was closed).
        """
        return self._exchange(command, timeout_s)[0]

    def act(self, command: str) -> float:
        """Send a command that changes what the unit does (``stepu``, ``stop``) as :meth:`query`
        does; return how long ago the unit received it (s): half the link's shortest round trip
        after the line was written.  A unit acts on a command as it arrives and may answer
        only after work of its own (firmware_sim's ``stepu`` regenerates 100 ms of waveform
        first: a 6-10 ms round trip where ``stop`` takes 1 ms), which the midpoint of the
        command's own round trip would count as time before it acted."""
        _, written_s, _ = self._exchange(command, None)  # which takes this round trip into the shortest
        return time.monotonic() - (written_s + 0.5 * self._shortest_s)

    def _exchange(self, command: str, timeout_s: float | None) -> tuple[list[str], float, float]:
        """:meth:`query`'s lines, and the clock (``time.monotonic``) when the line was written
        and when its reply was complete."""
        with self.lock:
            try:
                port = self._ready()
                port.reset_input_buffer()  # stray bytes from before are not our reply
                port.write(command.encode("ascii") + b"\r\n")
                written_s = time.monotonic()
                lines, error = self._read_reply(port, timeout_s or self.timeout_s, command)
                replied_s = time.monotonic()
            except QUERY_ERRORS as exc:
                self._lost(exc)
                lost = ReplyTimeout if isinstance(exc, ReplyTimeout) else AmplifierLinkLost
                raise lost(f"{self.url}: {command.split()[0]}: {exc}") from exc
            self._shortest_s = min(self._shortest_s, replied_s - written_s)
            if error is not None:
                raise AmplifierError(f"{self.url}: {command.split()[0]}: {error}")
            return lines, written_s, replied_s

    def value(self, command: str, name: str) -> str:
        """The value of the ``name = value [unit]`` line of ``command``'s reply."""
        for line in self.query(command):
            match = _VALUE.match(line)
            if match and match.group(1) == name:
                return match.group(2)
        with self.lock:  # another command's reply: out of step, resynchronise
            self._lost(None)
        raise AmplifierLinkLost(f"{self.url}: {command}: no '{name} = ...' line in the reply")

    def attach(self, axis: int, stopped: Callable[[], None]) -> None:
        """Stop ``axis`` when the link resynchronises after a lost reply (the unit may still
        step); ``stopped`` is called (lock held: it must not query) once the unit acknowledged."""
        with self.lock:
            self._axes.setdefault(axis, []).append(stopped)

    def close(self) -> None:
        """Close the port for good: a later command raises :class:`AmplifierLinkLost` rather than
        reopening it (a dead simulator's pty path may be another program's by then, and a serial
        port reopened by a stray command would be held, exclusively, from every reconnect)."""
        with self.lock:
            self._closed = True
            self._drop()

    # -- internals (lock held) -------------------------------------------------

    @property
    def _greets(self) -> bool:
        """The console greets every connection (the ANC300's TCP console, ``socket://``)."""
        return self.url.startswith("socket://")

    @property
    def _networked(self) -> bool:
        """A network link: after a timeout a new connection is the way back (the old one may be
        half-open); a serial port stays open (closing it resets nothing on the unit)."""
        return self.url.startswith(("socket://", "rfc2217://"))

    def _drop(self) -> None:
        self._in_sync = False
        self._shortest_s = math.inf  # the next connection may take another path
        if self._port is not None:
            with contextlib.suppress(*LINK_ERRORS):
                self._port.close()
            self._port = None

    def _lost(self, exc: BaseException | None) -> None:
        """A reply went missing or the link broke (``exc``; None: a reply that was not the
        command's): resynchronise before the next command, and stop the axes then."""
        self._in_sync = False
        if self.version:  # commands went out: one of them may have started a burst
            self._stop_pending = True
        if exc is not None and (self._networked or not isinstance(exc, ReplyTimeout)):
            self._drop()

    def _ready(self) -> serial.SerialBase:
        """The port, connected and in step with the console."""
        if self._closed:
            raise AmplifierLinkLost("the link is closed")
        if self._port is None:
            return self._connect()
        if not self._in_sync:
            self._resync(self._port, drain=True)
        return self._port

    def _open(self) -> serial.SerialBase:
        try:
            # pyserial's rfc2217 client has no write timeout
            write_timeout = None if self.url.startswith("rfc2217://") else self.timeout_s
            options = {"baudrate": self.baudrate, "timeout": self.timeout_s, "write_timeout": write_timeout}
            if self._greets:
                return _GreetingSocket(self.url, **options)
            # exclusive: a second program opening the device with pyserial (another daemon,
            # pymeasure) is refused instead of interleaving its commands with ours
            return serial.serial_for_url(self.url, exclusive=True, **options)
        except (serial.SerialException, OSError, ValueError) as exc:
            if "exclusively lock" in str(exc):
                raise AmplifierLinkLost(f"cannot open {self.url}: in use by another program ({exc})") from exc
            raise AmplifierLinkLost(f"cannot open: {exc}") from exc

    def _connect(self) -> serial.SerialBase:
        port = self._open()
        self._port = port
        with contextlib.ExitStack() as undo:  # any failure from here drops the port
            undo.callback(self._drop)
            # a serial port may hold what a previous session left unread; a new TCP
            # connection holds nothing stale, only the greeting (read next: never flushed)
            if not self._greets:
                port.reset_input_buffer()
            # on a serial port this also drains what the console sends until it is quiet
            if self._asks_password(port):
                self._login(port)
            self._resync(port, drain=False)
            undo.pop_all()
        return port

    def _resync(self, port: serial.SerialBase, drain: bool) -> None:
        """Get in step with the console without relying on it dropping anything: drain (when
        ``drain``), ``ver`` up to its reply (everything before it is stale), ``echo off``; then,
        after a lost reply, ``stop`` every attached axis."""
        if drain:
            dropped = self._drain(port)
            if dropped:
                log.debug("%s: %d stale bytes drained", self.url, dropped)
        for _ in range(2):
            if self._identify(port):
                break
            self._login(port)  # the console asked for the password (a late prompt)
        else:
            raise AmplifierLinkLost("the console asks for the password again after a login")
        # in step now: echo off's OK is its own; a ver reply before it is that of an
        # earlier resync whose ver timed out (the unit answers in order), skipped
        port.write(b"echo off\r\n")
        deadline = time.monotonic() + self.timeout_s
        while True:
            lines, error = self._read_reply(port, deadline - time.monotonic(), "echo off")
            if error is not None:
                raise AmplifierLinkLost(f"'echo off' refused: {error}")
            if not any(line.startswith(IDENTITY) for line in lines):
                break
        self._in_sync = True
        if self._stop_pending:
            self._stop_axes(port)

    def _drain(self, port: serial.SerialBase) -> int:
        """Read and discard until the line has been silent :data:`RESYNC_QUIET_S` (at most
        :data:`RESYNC_DRAIN_MAX_S`); the number of bytes discarded."""
        start = time.monotonic()
        quiet_until, end = start + RESYNC_QUIET_S, start + RESYNC_DRAIN_MAX_S
        dropped = 0
        while (wait := min(quiet_until, end) - time.monotonic()) > 0:
            port.timeout = wait
            chunk = port.read(max(1, port.in_waiting))
            if chunk:
                dropped += len(chunk)
                quiet_until = time.monotonic() + RESYNC_QUIET_S
        return dropped

    def _identify(self, port: serial.SerialBase) -> bool:
        """Send ``ver`` and read up to its reply (first line starting :data:`IDENTITY`, then
        ``OK``), discarding everything before it; False when the console asks for the password.

        No such reply within ``timeout_s``: a device that answered something else at the first
        connect is no ANC300 (:class:`AmplifierError`, naming the port and what it answered);
        otherwise the link is lost (:class:`ReplyTimeout`).
        """
        port.write(b"ver\r\n")
        deadline = time.monotonic() + self.timeout_s
        reply: list[str] | None = None
        skipped: list[str] = []
        while True:
            try:
                line = self._readline(port, deadline)
            except ReplyTimeout:
                if skipped and not self.version:
                    shown = " | ".join(skipped)[:SHOWN_CHARS]
                    raise AmplifierError(
                        f"{self.url}: not an attocube ANC300: 'ver' was answered {shown!r}"
                    ) from None
                raise ReplyTimeout(f"no answer to 'ver' within {self.timeout_s:g} s") from None
            if line.startswith("Authorization code"):  # a late prompt (+ the masked command)
                continue
            if line.startswith("Authorization"):  # ver was taken as a password
                return False
            if line.startswith(IDENTITY):
                reply = [line]
            elif reply is not None and line == "OK":
                if skipped:
                    log.debug("%s: skipped before the ver reply: %s", self.url, skipped)
                self.version = reply
                return True
            elif line in ("OK", "ERROR"):  # the end of a stale reply
                reply = None
                skipped.append(line)
            elif reply is not None:
                reply.append(line)
            elif line and line != "ver":
                skipped.append(line)

    def _stop_axes(self, port: serial.SerialBase) -> None:
        """``stop`` every attached axis (a lost reply may have left one stepping)."""
        for axis, callbacks in sorted(self._axes.items()):
            port.write(f"stop {axis}\r\n".encode("ascii"))
            _, error = self._read_reply(port, self.timeout_s, f"stop {axis}")
            if error is not None:
                log.warning("%s: stop %d after resynchronising: %s", self.url, axis, error)
                continue
            for stopped in callbacks:
                stopped()
        if self._axes:
            log.warning(
                "%s: resynchronised after a lost reply; axes %s stopped", self.url, sorted(self._axes)
            )
        self._stop_pending = False

    def _login(self, port: serial.SerialBase) -> None:
        port.write(self.password.encode("ascii") + b"\r\n")
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            line = self._readline(port, deadline)
            if line == "Authorization success":
                return
            if line.startswith("Authorization failed"):
                raise AmplifierError(f"{self.url}: wrong password")
        raise AmplifierLinkLost("no answer to the password")

    def _asks_password(self, port: serial.SerialBase) -> bool:
        """Read the greeting up to the password prompt (True) or the console prompt (False).

        On ``socket://`` (the ANC300's TCP console greets every connection) a greeting
        line must arrive within ``timeout_s``, and the prompt is awaited as long; a
        serial port silent for :data:`GREETING_QUIET_S` asks for nothing.
        """
        required = self._greets
        start = time.monotonic()
        deadline = start + self.timeout_s
        quiet_until = deadline if required else start + GREETING_QUIET_S
        seen = b""
        while b"Authorization code" not in seen:
            if seen.rstrip().endswith(b">"):
                return False
            wait = min(deadline, quiet_until) - time.monotonic()
            if wait <= 0:
                if required and b"\n" not in seen:
                    raise AmplifierLinkLost(f"no greeting within {self.timeout_s:g} s")
                return False
            port.timeout = wait
            chunk = port.read(max(1, port.in_waiting))
            seen += chunk
            if chunk and not required:
                quiet_until = time.monotonic() + GREETING_QUIET_S
        return True

    @staticmethod
    def _readline(port: serial.SerialBase, deadline: float) -> str:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise ReplyTimeout("timeout")
        port.timeout = remaining
        raw = port.read_until(b"\n")
        if not raw.endswith(b"\n"):
            raise ReplyTimeout("timeout")
        return raw.decode("ascii", errors="replace").strip().removeprefix(">").strip()

    def _read_reply(
        self, port: serial.SerialBase, timeout_s: float, command: str
    ) -> tuple[list[str], str | None]:
        """Data lines and the error message (None after ``OK``)."""
        deadline = time.monotonic() + timeout_s
        lines: list[str] = []
        while True:
            line = self._readline(port, deadline)
            if line == "OK":
                return lines, None
            if line == "ERROR":
                return lines[:-1], (lines[-1] if lines else "ERROR")
            if line.startswith("Authorization code"):  # a late prompt (+ the masked command)
                continue
            if line.startswith("Authorization"):  # the command was taken as a password
                return lines, "Authorization required"
            if line and line != command:
                lines.append(line)
