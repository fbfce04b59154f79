"""One axis of an ANC300-compatible amplifier (attocube ANC300, firmware_sim): :class:`Anc300Amplifier`.

It sits behind an :class:`~feeder.drivers.anc300_link.Anc300Link` (the connection: login,
identity, resynchronisation) and implements :class:`~feeder.drivers.amplifier.Amplifier`.
Protocol: docs/anc300-protocol.md.

The driver speaks only a real ANC300's verbs
(:data:`feeder.protocol.anc300.MOVE_PATH`), so it drives an attocube ANC300
and firmware_sim alike: the flyback goes up as 256-point ``setpu``/``setpd``
tables (:meth:`feeder.waveform.Waveform.anc300_tables`, uploaded when they
change); the frequency goes out in whole hertz (what an ANC300 takes) and f is
the unit's own ``getf`` answer; the end of a burst is N/f after the step
command reached the unit (:meth:`~feeder.drivers.anc300_link.Anc300Link.act`),
confirmed with ``stepw``; the step counter is the
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

import logging
import math
import threading
import time
from collections.abc import Callable

from feeder.drivers.amplifier import (
    Amplifier,
    AmplifierError,
    AmplifierLinkLost,
    AmplifierStatus,
    DriveSettings,
)
from feeder.drivers.anc300_link import DEFAULT_BAUDRATE, Anc300Link, ReplyTimeout
from feeder.protocol.anc300 import DEFAULT_PASSWORD
from feeder.waveform import Waveform

BURST_END_MARGIN_S = 0.002
"""``moving`` stays True this long past N/f (the burst starts at the DAC's next sample)."""

log = logging.getLogger(__name__)


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
        self._offset_mode = False  # this driver put the axis in ``off`` (hold_offset)
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
        started = self._acted_at(f"{verb} {self.axis} {abs(count)}")
        with self._lock:
            self._settle_burst()
            self._continuous = False
            self._burst = (started, count)
            self._counter += count
            self._estimated = False

    def run_continuous(self, forward: bool) -> None:
        self.link.query(f"{'stepu' if forward else 'stepd'} {self.axis} c")
        with self._lock:
            self._cut_burst()
            self._continuous = True

    def stop(self) -> None:
        stopped = self._acted_at(f"stop {self.axis}")
        with self._lock:
            self._cut_burst(stopped)

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
        if self._offset_mode:  # grounded: a later ``setm off`` starts from 0 V, not from it
            self._offset_mode = False
            self.link.query(f"seta {self.axis} 0")
        with self._lock:
            self._cut_burst()

    def enable(self) -> None:
        self._offset_mode = False
        self.link.query(f"setm {self.axis} stp")

    def hold_offset(self, volts: float) -> None:
        """``seta`` the level, then ``setm off`` (the offset mode) unless this driver set it:
        from ``gnd`` at 0 V that changes nothing the plate feels."""
        self.link.query(f"seta {self.axis} {volts:.6f}")
        if not self._offset_mode:
            try:
                self.link.query(f"setm {self.axis} off")
            except AmplifierLinkLost:
                raise
            except AmplifierError as err:  # the unit refused the mode: its module has none
                raise AmplifierError(
                    f"{err}: axis {self.axis} holds no offset (offset mode; an ANM150 module has none), "
                    "so the plate cannot be moved by offsets: calibrate the camera from moves you "
                    "measure (feeder vision calibrate --x-move ... --y-move ...) or set [camera] aligned"
                ) from err
            self._offset_mode = True

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

    def _acted_at(self, command: str) -> float:
        """Send ``command`` (:meth:`Anc300Link.act`); when the unit acted on it, by ``clock``."""
        ago = self.link.act(command)
        return self._clock() - ago

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
