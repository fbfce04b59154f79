"""Serial/TCP driver for ANC300-compatible amplifiers (attocube ANC300, firmware_sim).

The link is pyserial's ``serial_for_url``, so one driver speaks to a device
path (``/dev/ttyUSB0``, a pty), ``socket://HOST:7230`` (the ANC300's TCP
console) or ``rfc2217://HOST:PORT`` (a serial port behind a network server).
Protocol: docs/anc300-protocol.md.

- :class:`Anc300Link` is one connection: a lock (one command at a time, so
  any number of threads may share it), a timeout per reply, login when the
  device asks for a password (the TCP console always greets and asks; a
  serial port may stay silent), ``echo off``, and recovery: any timeout, broken
  reply or I/O error closes the port and raises
  :class:`~feeder.drivers.amplifier.AmplifierLinkLost`; the next command
  reconnects and resynchronises (flush, ``echo off``, read up to ``OK``).
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
        self._port: serial.SerialBase | None = None

    # -- public ---------------------------------------------------------------

    def query(self, command: str, timeout_s: float | None = None) -> list[str]:
        """Send one command line; return its data lines.

        Raises :class:`AmplifierError` on an ``ERROR`` reply (message = the
        device's error line) and :class:`AmplifierLinkLost` when no complete
        reply came within the timeout or the link broke (then the port is
        closed and the next query reconnects).
        """
        with self.lock:
            try:
                port = self._port if self._port is not None else self._connect()
                port.reset_input_buffer()  # stray bytes from before are not our reply
                port.write(command.encode("ascii") + b"\r\n")
                lines, error = self._read_reply(port, timeout_s or self.timeout_s, command)
            except QUERY_ERRORS as exc:
                self._drop()
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
        with self.lock:
            self._drop()
        raise AmplifierLinkLost(f"{self.url}: {command}: no '{name} = ...' line in the reply")

    def close(self) -> None:
        with self.lock:
            self._drop()

    # -- internals (lock held) -------------------------------------------------

    @property
    def _greets(self) -> bool:
        """The console greets every connection (the ANC300's TCP console, ``socket://``)."""
        return self.url.startswith("socket://")

    def _drop(self) -> None:
        if self._port is not None:
            with contextlib.suppress(*LINK_ERRORS):
                self._port.close()
            self._port = None

    def _connect(self) -> serial.SerialBase:
        try:
            # pyserial's rfc2217 client has no write timeout
            write_timeout = None if self.url.startswith("rfc2217://") else self.timeout_s
            opener = _GreetingSocket if self._greets else serial.serial_for_url
            port = opener(
                self.url, baudrate=self.baudrate, timeout=self.timeout_s, write_timeout=write_timeout
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise AmplifierLinkLost(f"cannot open: {exc}") from exc
        self._port = port
        with contextlib.ExitStack() as undo:  # any failure from here drops the port
            undo.callback(self._drop)
            # a serial port may hold what a previous session left unread; a new TCP
            # connection holds nothing stale, only the greeting (read next: never flushed)
            if not self._greets:
                port.reset_input_buffer()
            if self._asks_password(port):
                self._login(port)
            # resynchronise: echo off, then everything up to its OK is discarded
            for _ in range(2):
                port.write(b"echo off\r\n")
                _, error = self._read_reply(port, self.timeout_s, "echo off")
                if error is None:
                    undo.pop_all()
                    return port
                if "Authorization" in error:
                    self._login(port)
            raise AmplifierLinkLost("device refuses 'echo off'")

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
        except ReplyTimeout:  # still playing (a closed link is lost: the daemon grounds, reconnects)
            return False
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
