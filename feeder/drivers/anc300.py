"""Serial/TCP driver for ANC300-compatible amplifiers (attocube ANC300, firmware_sim).

The link is pyserial's ``serial_for_url``, so one driver speaks to a device
path (``/dev/ttyUSB0``, a pty), ``socket://HOST:7230`` (the ANC300's TCP
console) or ``rfc2217://HOST:PORT`` (a serial port behind a network server).
Protocol: docs/anc300-protocol.md.

- :class:`Anc300Link` is one connection: a lock (one command at a time, so
  any number of threads may share it), a timeout per reply, login when the
  device asks for a password (the TCP console always greets and asks; a
  serial port may stay silent), an identity check (``ver``), ``echo off``, and
  recovery that does not rely on the unit dropping anything: a real ANC300's
  serial console keeps its session and every unread reply when the port is
  closed (no reset on DTR), so a late reply would answer the next command.  Any
  timeout, broken reply or I/O error raises
  :class:`~feeder.drivers.amplifier.AmplifierLinkLost` (a timeout:
  :class:`ReplyTimeout`); an I/O error (or a timeout on a network console)
  closes the port.  The next command first resynchronises: it drains what
  arrives until the line is quiet, sends ``ver`` and discards everything up to
  the reply that starts ``attocube ANC300`` and its ``OK``, then ``echo off``
  (a second ``ver`` reply before its ``OK`` is a stale one, skipped too), and
  after a lost reply sends ``stop`` to every axis on the link before the
  command.  Serial ports are opened exclusively (another program using pyserial's
  lock cannot interleave).
- :class:`Anc300Amplifier` is one axis behind a link, implementing
  :class:`~feeder.drivers.amplifier.Amplifier`.

The driver speaks only a real ANC300's verbs
(:data:`feeder.protocol.anc300.MOVE_PATH`), so it drives an attocube ANC300
and firmware_sim alike: the flyback goes up as 256-point ``setpu``/``setpd``
tables (:meth:`feeder.waveform.Waveform.anc300_tables`, uploaded when they
change); the frequency goes out in whole hertz (what an ANC300 takes) and f is
the unit's own ``getf`` answer; the end of a burst is N/f after the step
command was acknowledged, confirmed with ``stepw``; the step counter is the
driver's own count of the steps it commanded, and after a ``stop`` mid-burst
the steps played are *estimated* from the time the burst ran
(``AmplifierStatus.counted_by`` says so): the ANC300 reports neither a counter
nor a fault word.  Example::

    link = Anc300Link("socket://192.168.1.2:7230", password="123456")
    with Anc300Amplifier(link, axis=1) as amp:
        amp.apply(DriveSettings(frequency_hz=100, amplitude_v=40.0))
        amp.enable(); amp.step(10); amp.wait(5.0); amp.ground()
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
    Amplifier,
    AmplifierError,
    AmplifierLinkLost,
    AmplifierStatus,
    DriveSettings,
)
from feeder.protocol.anc300 import DEFAULT_PASSWORD
from feeder.waveform import Waveform

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
BURST_END_MARGIN_S = 0.002
"""``moving`` stays True this long past N/f (the burst starts at the DAC's next sample)."""
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

    # -- public ---------------------------------------------------------------

    def query(self, command: str, timeout_s: float | None = None) -> list[str]:
        """Send one command line; return its data lines.

        Raises :class:`AmplifierError` on an ``ERROR`` reply (message = the
        device's error line) or when the device is no ANC300, and
        :class:`AmplifierLinkLost` when no complete reply came within the
        timeout (:class:`ReplyTimeout`) or the link broke; the next query then
        resynchronises (and reconnects, if the port was closed).
        """
        with self.lock:
            try:
                port = self._ready()
                port.reset_input_buffer()  # stray bytes from before are not our reply
                port.write(command.encode("ascii") + b"\r\n")
                lines, error = self._read_reply(port, timeout_s or self.timeout_s, command)
            except QUERY_ERRORS as exc:
                self._lost(exc)
                lost = ReplyTimeout if isinstance(exc, ReplyTimeout) else AmplifierLinkLost
                raise lost(f"{self.url}: {command.split()[0]}: {exc}") from exc
            if error is not None:
                raise AmplifierError(f"{self.url}: {command.split()[0]}: {error}")
            return lines

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
        with self.lock:
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


class Anc300Amplifier(Amplifier):
    """One axis of an ANC300-compatible amplifier behind an :class:`Anc300Link`.

    Only a real ANC300's verbs are sent (see the module docstring).  ``clock``
    is the time base of the host's burst bookkeeping (``time.monotonic``).
    """

    def __init__(self, link: Anc300Link, axis: int = 1, clock: Callable[[], float] = time.monotonic) -> None:
        self.link = link
        self.axis = axis
        self._clock = clock
        self._lock = threading.Lock()
        self._counter = 0  # steps commanded (played, once a burst is over)
        self._tables: tuple[list[int], list[int]] | None = None  # what the device holds
        self._frequency_hz = 0.0  # the unit's own (getf), Hz
        self._burst: tuple[float, int] | None = None  # (start s, signed steps) while it runs
        self._estimated = False
        self._continuous = False  # stepu/stepd c: never ends, so never ``stepw``
        link.attach(axis, self._stopped_by_link)

    @classmethod
    def open(
        cls,
        url: str,
        axis: int = 1,
        password: str = DEFAULT_PASSWORD,
        timeout_s: float = 1.0,
        baudrate: int = DEFAULT_BAUDRATE,
    ) -> Anc300Amplifier:
        """A driver on a new link to ``url`` (timeout_s in s, baudrate in bit/s)."""
        return cls(Anc300Link(url, password=password, timeout_s=timeout_s, baudrate=baudrate), axis)

    def apply(self, settings: DriveSettings) -> None:
        """Send the frequency in whole hertz and keep the unit's ``getf`` answer for the
        burst bookkeeping; then the amplitude and (when they changed) the tables."""
        a = self.axis
        self.link.query(f"setf {a} {round(settings.frequency_hz)}")
        frequency = self._number(f"getf {a}", "frequency")
        if frequency != settings.frequency_hz:
            log.debug("axis %d: %g Hz asked, the unit runs at %g Hz", a, settings.frequency_hz, frequency)
        with self._lock:
            self._frequency_hz = frequency
        self.link.query(f"setv {a} {settings.amplitude_v:.6f}")
        tables = Waveform(
            frequency_hz=frequency,
            amplitude_vpp=1.0,
            flyback_shape=settings.flyback_shape,
            flyback_s=settings.flyback_s,
        ).anc300_tables()
        if tables != self._tables:
            self._tables = None  # unknown until both went through
            self.link.query(f"setpu {a} " + " ".join(map(str, tables[0])))
            self.link.query(f"setpd {a} " + " ".join(map(str, tables[1])))
            self._tables = tables

    def step(self, count: int) -> None:
        if count == 0:
            raise AmplifierError("step count 0 refused (stepu 0 runs forever on an ANC300)")
        verb = "stepu" if count > 0 else "stepd"
        sent = self._clock()
        self.link.query(f"{verb} {self.axis} {abs(count)}")
        with self._lock:
            self._settle_burst()
            self._continuous = False
            # the unit started between sending and its OK: the midpoint halves the error
            self._burst = (0.5 * (sent + self._clock()), count)
            self._counter += count
            self._estimated = False

    def run_continuous(self, forward: bool) -> None:
        self.link.query(f"{'stepu' if forward else 'stepd'} {self.axis} c")
        with self._lock:
            self._cut_burst()
            self._continuous = True

    def stop(self) -> None:
        sent = self._clock()
        self.link.query(f"stop {self.axis}")
        with self._lock:
            self._cut_burst(0.5 * (sent + self._clock()))

    def wait(self, timeout_s: float) -> bool:
        """Sleep until N/f after the burst started, then confirm with ``stepw``."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            remaining = math.inf if self._continuous else self._remaining_s()
        if remaining > timeout_s:
            time.sleep(timeout_s)
            return False
        time.sleep(max(0.0, remaining))
        try:
            self.link.query(f"stepw {self.axis}", timeout_s=max(0.05, deadline - time.monotonic()))
        except ReplyTimeout:  # still playing (the link resynchronises and stops the axes before
            return False  # the next command; a closed link is lost: the daemon grounds, reconnects)
        with self._lock:
            self._burst = None
        return True

    def ground(self) -> None:
        self.link.query(f"setm {self.axis} gnd")
        with self._lock:
            self._cut_burst()

    def enable(self) -> None:
        self.link.query(f"setm {self.axis} stp")

    def steps_played(self) -> tuple[int, bool]:
        """(signed steps played since this driver started, estimated?) — no I/O."""
        with self._lock:
            self._settle_burst()
            if self._burst is not None:
                start, count = self._burst
                return self._counter - count + self._played(start, count), True
            return self._counter, self._estimated

    def status(self) -> AmplifierStatus:
        mode = self.link.value(f"getm {self.axis}", "mode")
        frequency = self._number(f"getf {self.axis}", "frequency")
        amplitude = self._number(f"getv {self.axis}", "voltage")
        counter, estimated = self.steps_played()
        with self._lock:
            moving = self._burst is not None or self._continuous
        return AmplifierStatus(
            mode=mode,
            frequency_hz=frequency,
            amplitude_v=amplitude,
            step_counter=counter,
            moving=moving,
            counted_by="estimated" if estimated else "host",
        )

    def close(self) -> None:
        self.link.close()

    def _number(self, command: str, name: str) -> float:
        """The finite number of ``command``'s ``name = value [unit]`` line."""
        text = self.link.value(command, name)
        try:
            number = float(text)
        except ValueError:
            number = math.nan
        if not math.isfinite(number):
            raise AmplifierError(f"{self.link.url}: {command}: {name} = {text!r} is not a number")
        return number

    def _stopped_by_link(self) -> None:
        """The link stopped this axis while resynchronising (a reply was lost): a burst ends now,
        its steps estimated."""
        with self._lock:
            self._cut_burst(self._clock())

    # -- burst bookkeeping (lock held) -------------------------------------------

    def _remaining_s(self) -> float:
        if self._burst is None or self._frequency_hz <= 0:
            return 0.0
        start, count = self._burst
        return start + abs(count) / self._frequency_hz + BURST_END_MARGIN_S - self._clock()

    def _played(self, start: float, count: int, at: float | None = None) -> int:
        """Steps of a burst played by ``at`` (default now), from the time it ran (sign of
        ``count``)."""
        if self._frequency_hz <= 0:
            return 0
        now = self._clock() if at is None else at
        done = min(abs(count), max(0, round((now - start) * self._frequency_hz)))
        return done if count > 0 else -done

    def _settle_burst(self) -> None:
        """Forget a burst that is over by the clock (all its steps played)."""
        if self._burst is not None and self._remaining_s() <= 0:
            self._burst = None

    def _cut_burst(self, at: float | None = None) -> None:
        """The output stopped (at clock time ``at``, default now): keep only the steps played
        by then (estimated)."""
        self._continuous = False
        self._settle_burst()
        if self._burst is not None:
            start, count = self._burst
            self._counter += self._played(start, count, at) - count
            self._burst = None
            self._estimated = True
