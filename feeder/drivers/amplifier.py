"""The one interface every amplifier link implements (serial console, CANopen).

Modelled on python-can's ``BusABC``: one abstract class, transports as
implementations.  Units are SI; voltages are the amplifier's output in volts
peak-to-peak of the sawtooth.  A driver drives one axis.
"""

from __future__ import annotations

import math
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from types import TracebackType

from feeder.errors import FeederError


class AmplifierError(FeederError, RuntimeError):
    """The amplifier answered with an error, or refused a value."""


class AmplifierLinkLost(AmplifierError):
    """No answer within the link's timeout: cable, process or node gone."""


FLYBACK_SHAPES = ("linear", "half-cosine", "current-limited")


@dataclass(frozen=True)
class DriveSettings:
    """What the amplifier needs to produce a stepping sawtooth.

    frequency_hz: sawtooth frequency (one step per period).
    amplitude_v: peak-to-peak amplitude in volts.
    flyback_shape: one of :data:`FLYBACK_SHAPES`.
    flyback_s: flyback duration for ``linear``/``half-cosine``; ``None`` lets the
        amplifier's current limit set it (``current-limited``).
    """

    frequency_hz: float
    amplitude_v: float
    flyback_shape: str = "current-limited"
    flyback_s: float | None = None


@dataclass(frozen=True)
class AmplifierStatus:
    """A snapshot of one axis.

    mode: ``gnd`` (output grounded), ``stp`` (stepping allowed), ``off`` ...
    step_counter: signed count of steps executed since power-up (+ forward).
    moving: a step burst or continuous stepping is in progress.
    fault_word: bit field, 0 = healthy; ``faults`` names the bits that are set.
    counted_by: who counted ``step_counter``: ``drive`` (the amplifier counts the
        periods it plays), ``host`` (the driver's count of what it commanded; an
        ANC300 counts nothing) or ``estimated`` (a stop cut a burst short and the
        steps played were estimated from the time it ran).
    """

    mode: str
    frequency_hz: float
    amplitude_v: float
    step_counter: int
    moving: bool
    fault_word: int = 0
    faults: tuple[str, ...] = field(default_factory=tuple)
    counted_by: str = "drive"


class Amplifier(ABC):
    """One axis of a stick-slip amplifier.

    Every method may raise :class:`AmplifierLinkLost` (no answer within the
    timeout) or :class:`AmplifierError` (the device refused).  Implementations
    are thread-safe: one lock per link.
    """

    @abstractmethod
    def apply(self, settings: DriveSettings) -> None:
        """Configure frequency, amplitude and flyback for the next steps."""

    @abstractmethod
    def step(self, count: int) -> None:
        """Start a burst of ``abs(count)`` steps, forward (+) or backward (−).

        Returns at once; use :meth:`wait` or :meth:`status` to follow it.
        ``count == 0`` is refused (on a real ANC300 ``stepu 0`` runs forever).
        """

    @abstractmethod
    def run_continuous(self, forward: bool) -> None:
        """Step until :meth:`stop`."""

    @abstractmethod
    def stop(self) -> None:
        """Stop stepping at once (the output stays in step mode)."""

    @abstractmethod
    def wait(self, timeout_s: float) -> bool:
        """Block until the burst is done; False when ``timeout_s`` ran out first."""

    @abstractmethod
    def ground(self) -> None:
        """Ground the output (the safe state)."""

    @abstractmethod
    def enable(self) -> None:
        """Leave ground: put the axis in step mode."""

    @abstractmethod
    def status(self) -> AmplifierStatus:
        """Read the axis' state."""

    def steps_played(self) -> tuple[int, bool]:
        """(signed steps played since the driver started, whether that is an estimate).

        Drives that count steps read their counter; hosts of drives that do not
        (the ANC300) count what they commanded and estimate a cut burst from time.
        """
        status = self.status()
        return status.step_counter, status.counted_by == "estimated"

    def hold_offset(self, volts: float) -> None:
        """Hold the output at ``volts`` DC (the offset mode: an ANC300's ``setm off``/``seta``):
        the stack's static stroke moves the plate by its gain × volts.

        The level changes at the amplifier's slope limit, as fast as a flyback: a jump of more
        than a fraction of a volt makes the parts slip; :meth:`ramp_offset` changes it gently.
        :meth:`enable` (step mode) and :meth:`ground` end the offset at once: return it to 0 V
        first.  Default: refused (a drive without an offset mode).
        """
        raise AmplifierError(f"{type(self).__name__}: this drive has no DC offset mode")

    def ramp_offset(
        self,
        start_v: float,
        end_v: float,
        increment_v: float,
        pause_s: float,
        stop: threading.Event | None = None,
    ) -> int:
        """Move the offset from ``start_v`` to ``end_v`` in increments of at most ``increment_v``
        (V), ``pause_s`` (s) apart or a round trip when that is longer (the plate's ringing dies
        out between them); returns the increments made (fewer when ``stop`` was set: the
        offset stays where it got).

        Each increment is a small jump at the slope limit: its ringing must stay below the
        parts' breakaway acceleration (firmware_sim's plate, 30 kHz, and a 105 m/s² part:
        0.05 V and 0.1 V increments hold, 0.2 V ones slip; docs/vision.md)."""
        if not increment_v > 0:
            raise AmplifierError(f"offset increment must be positive, got {increment_v!r} V")
        count = max(1, math.ceil(abs(end_v - start_v) / increment_v))
        due = time.monotonic()
        for k in range(1, count + 1):
            time.sleep(max(0.0, due - time.monotonic()))
            if stop is not None and stop.is_set():
                return k - 1
            self.hold_offset(start_v + (end_v - start_v) * k / count)
            # on a fixed beat: a late increment shortens the next gap, never below half a pause
            due = max(due + pause_s, time.monotonic() + 0.5 * pause_s)
        time.sleep(max(0.0, due - time.monotonic()))
        return count

    def alive(self) -> None:  # noqa: B027 (optional hook: most drives have no host watchdog)
        """The caller's control loop is making progress; a drive with a host watchdog stops
        hearing the host when these stop.

        Call it often (every tick); it only sets a timestamp.  Default: does nothing.
        """

    @abstractmethod
    def close(self) -> None:
        """Release the link (does not change the output)."""

    def __enter__(self) -> Amplifier:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
