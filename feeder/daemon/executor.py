"""The I/O half of the loop: amplifier round trips and record writes, off the tick's thread.

:class:`AmplifierExecutor` runs the policy's :class:`~feeder.daemon.jobs.Command`s
on a worker thread, one at a time and in order, and reports each as a
:class:`~feeder.daemon.jobs.Completion`.  A ``stop`` jumps the queue: it
drops the commands not yet started and goes out next (on a serial link it
still waits for the one round trip in flight, never for a burst: bursts end
by the clock, ``stepw`` is only sent once N/f has passed).

:class:`RecordWriter` runs the store's writes (move records, positions,
calibration) on its own thread in order, so a slow commit never delays a tick.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator, Mapping

from feeder.daemon.jobs import Command, Completion, StepMode
from feeder.daemon.log_throttle import LogThrottle
from feeder.drivers.amplifier import Amplifier, AmplifierError, AmplifierLinkLost
from feeder.errors import FeederError

log = logging.getLogger(__name__)

CLEARABLE_FAULTS = frozenset({"watchdog", "host_watchdog"})
"""Latched amplifier faults a new move may clear: transient, their cause is gone when a move
comes (the firmware's tick was late; the node missed a host's heartbeat, e.g. a daemon that
died mid-move: the host sending this move beats)."""


class AmplifierExecutor:
    """Runs amplifier commands on a worker thread; completions come back through :meth:`take`.

    amplifiers: one driver per axis (``"x"``, ``"y"``, ``"theta"``), or one driver for x;
    modes: each axis' waveform modes.  ``enable`` and ``stop`` act on every axis.
    """

    def __init__(
        self,
        amplifiers: Amplifier | Mapping[str, Amplifier],
        modes: Mapping[str, Mapping[str, StepMode]],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.amplifiers = per_axis(amplifiers)
        self.modes = modes
        self._clock = clock
        self._cond = threading.Condition()
        self._queue: collections.deque[Command] = collections.deque()
        self._done: list[Completion] = []
        self._closing = False
        self._running = False  # a command is in flight
        self._lent = False  # the amplifiers are lent out (lent()): the queue waits
        self._thread = threading.Thread(target=self._run, name="amplifier-executor", daemon=True)
        self._thread.start()

    def submit(self, command: Command) -> None:
        """Queue ``command``; a ``stop`` drops what is queued and goes first."""
        with self._cond:
            if command.kind == "stop":
                self._queue.clear()
                self._queue.appendleft(command)
            else:
                self._queue.append(command)
            self._cond.notify()

    def take(self) -> list[Completion]:
        """Completions since the last call, in order."""
        with self._cond:
            out, self._done = self._done, []
        return out

    @property
    def amplifier(self) -> Amplifier:
        """The x axis' driver."""
        return self.amplifiers["x"]

    def replace(self, amplifiers: Amplifier | Mapping[str, Amplifier]) -> None:
        """Use new links (after a reconnect); queued commands are dropped."""
        with self._cond:
            self._queue.clear()
            self.amplifiers = per_axis(amplifiers)

    @contextlib.contextmanager
    def lent(self) -> Iterator[dict[str, Amplifier]]:
        """The amplifiers, for the caller alone: waits for the command in flight; commands
        submitted meanwhile wait in the queue until the caller is done."""
        with self._cond:
            self._lent = True
            self._cond.wait_for(lambda: not self._running)
            amplifiers = self.amplifiers
        try:
            yield amplifiers
        finally:
            with self._cond:
                self._lent = False
                self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            self._closing = True
            self._queue.clear()
            self._cond.notify()
        self._thread.join(timeout=5.0)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: (self._queue and not self._lent) or self._closing)
                if self._closing:
                    return
                command = self._queue.popleft()
                amplifiers = self.amplifiers
                self._running = True
            completion = self._execute(amplifiers, command)
            with self._cond:
                self._done.append(completion)
                self._running = False
                self._cond.notify_all()

    def _execute(self, amplifiers: dict[str, Amplifier], command: Command) -> Completion:
        try:
            counter: int | None = None
            estimated = False
            amp = amplifiers[command.axis]
            if command.kind == "enable":
                for each in amplifiers.values():
                    self._enable(each)
            elif command.kind == "apply":
                amp.apply(self.modes[command.axis][command.mode].settings)
            elif command.kind == "step":
                counter = amp.steps_played()[0]
                amp.step(command.steps)
            elif command.kind == "confirm_end":
                if not amp.wait(command.timeout_s):
                    raise AmplifierError("the amplifier did not finish the burst in time")
            elif command.kind == "stop":
                for each in (amp, *(a for a in amplifiers.values() if a is not amp)):
                    each.stop()
                counter, estimated = amp.steps_played()
            elif command.kind == "ground":
                for each in amplifiers.values():
                    each.ground()
            else:
                raise ValueError(f"unknown command {command.kind!r}")
            return Completion(command, self._clock(), counter=counter, estimated=estimated)
        except AmplifierLinkLost as err:
            return Completion(command, self._clock(), error=str(err), link_lost=True)
        except AmplifierError as err:
            return Completion(command, self._clock(), error=str(err))
        except Exception as err:
            # the worker thread's one boundary: a driver failing in an unforeseen way is
            # reported as a lost link (grounded, reconnected), never lost
            log.exception("amplifier command %s failed unexpectedly", command.kind)
            return Completion(command, self._clock(), error=f"{type(err).__name__}: {err}", link_lost=True)

    @staticmethod
    def _enable(amp: Amplifier) -> None:
        """Leave ground.  A latched watchdog fault (:data:`CLEARABLE_FAULTS`) is cleared, as the
        new command is the user's; any other fault is reported."""
        status = amp.status()
        if status.fault_word:
            clear = getattr(amp, "clear_faults", None)
            others = set(status.faults) - CLEARABLE_FAULTS
            if clear is None or others or not status.faults:
                names = ", ".join(status.faults) or hex(status.fault_word)
                raise AmplifierError(f"amplifier fault latched: {names}")
            log.warning("clearing the amplifier's latched %s for a new move", ", ".join(status.faults))
            clear()
        amp.enable()


def per_axis(amplifiers: Amplifier | Mapping[str, Amplifier]) -> dict[str, Amplifier]:
    """One driver per axis; a group of axes (:class:`feeder.drivers.axes.Axes`) is kept as it is."""
    if isinstance(amplifiers, Amplifier):
        return {"x": amplifiers}
    if "x" not in amplifiers:
        raise ValueError("the amplifiers must include the x axis")
    return amplifiers if isinstance(amplifiers, dict) else dict(amplifiers)


class RecordWriter:
    """Runs record writes (SQLite) in order on one thread; :meth:`put` never blocks.

    A write that fails because the store cannot be written (disk full, I/O
    error) stays at the head of the queue and is retried every ``retry_s``;
    what comes after it waits in memory, in order, so nothing is lost or
    reordered.  ``on_unwritable(message)`` is called when such an outage
    starts and ``on_writable()`` when it ends.

    The thread's one boundary: a write that fails in any other way (a bug in a
    record callback) is logged with its traceback and dropped, as it would fail
    again: the writes behind it go on (a move's end record among them, which
    answers its caller; the thread had ended, every later move waiting for an
    answer that never came).  :attr:`dropped` counts them, :attr:`dropped_reason`
    says the last.  A bug in ``on_unwritable``/``on_writable`` is logged; the
    write it followed is not dropped for it.
    """

    def __init__(
        self,
        retry_s: float = 1.0,
        on_unwritable: Callable[[str], None] | None = None,
        on_writable: Callable[[], None] | None = None,
    ) -> None:
        self.retry_s = retry_s
        self.on_unwritable = on_unwritable
        self.on_writable = on_writable
        self.unwritable: str | None = None
        self.dropped = 0
        """Writes dropped for an unexpected error (a bug): their records are missing."""
        self.dropped_reason: str | None = None
        """The last dropped write's error (``Type: message``), or None."""
        self._cond = threading.Condition()
        self._queue: collections.deque[Callable[[], None]] = collections.deque()
        self._closing = False
        self._writing = False  # the head's write() is running (the boundary drops it if it fails)
        self._bug_log = LogThrottle(log)
        self._thread = threading.Thread(target=self._run, name="record-writer", daemon=True)
        self._thread.start()

    def put(self, write: Callable[[], None]) -> None:
        with self._cond:
            self._queue.append(write)
            self._cond.notify()

    def pending(self) -> int:
        """Writes queued (in memory), including one being retried."""
        with self._cond:
            return len(self._queue)

    def flush(self, timeout_s: float = 10.0) -> bool:
        """Wait until everything queued so far is written; False on timeout."""
        done = threading.Event()
        self.put(done.set)
        return done.wait(timeout_s)

    def close(self, timeout_s: float = 10.0) -> None:
        """Write what is queued (retrying for at most ``timeout_s``), then stop."""
        with self._cond:
            self._closing = True
            self._cond.notify()
        self._thread.join(timeout=timeout_s)
        left = self.pending()
        if left:
            log.error("%d record writes could not be made before shutdown: %s", left, self.unwritable)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._queue or self._closing)
                if not self._queue:
                    return
                write = self._queue[0]
            try:
                if not self._write(write):
                    return  # give up at shutdown; close() logs what is left
            except Exception as err:  # the writer thread's one boundary (the class docstring)
                self._failed(err)

    def _write(self, write: Callable[[], None]) -> bool:
        """Make ``write`` (the head of the queue) and take it off the queue, or hold it through a
        store outage (waiting ``retry_s``); False: give up (an outage at shutdown)."""
        self._writing = True
        try:
            write()
        except (FeederError, sqlite3.Error, OSError) as err:
            self._writing = False
            self._outage(str(err))
            with self._cond:
                if self._closing:
                    self._cond.wait(self.retry_s)
                    return not (self._closing and self.unwritable is not None)
                self._cond.wait(self.retry_s)
            return True
        self._writing = False
        with self._cond:
            self._queue.popleft()
        if self.unwritable is not None:
            log.warning("the state store is writable again")
            self.unwritable = None
            if self.on_writable is not None:
                self.on_writable()
        return True

    def _failed(self, err: Exception) -> None:
        """An unexpected error on the writer thread (:meth:`_run`'s boundary): the write that
        raised it is dropped (logged with the traceback; a repeat of the same error throttled)."""
        reason = f"{type(err).__name__}: {err}"
        if not self._writing:
            log.exception("record writer: a store outage callback failed")
            return
        self._writing = False
        with self._cond:
            self._queue.popleft()
            self.dropped += 1
            repeat, self.dropped_reason = reason == self.dropped_reason, reason
        if repeat:
            self._bug_log.warning("record writer: a record write failed again (%s); dropped", reason)
        else:
            log.exception("record writer: a record write failed unexpectedly; dropped, the writes "
                          "queued after it go on")  # fmt: skip

    def _outage(self, message: str) -> None:
        if self.unwritable is None:
            log.error("state store unwritable: %s; holding records in memory", message)
            self.unwritable = message
            if self.on_unwritable is not None:
                self.on_unwritable(message)
