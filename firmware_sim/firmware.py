"""The amplifier's firmware: tick loop, DAC buffer, safety; the axes in :mod:`firmware_sim.axis`.

Embedded style (DESIGN §6).  A fixed-period tick (default 1 kHz) hands the
samples the DAC played since the previous tick to the sinks (the world's
plant, test recorders) and tops up each axis' DAC buffer to ``dac_buffer_s``
(default 100 ms) ahead of the DAC's read pointer, the way a DMA ring in
circular mode with half-transfer interrupts is fed.  A tick that comes late by
less than the buffer depth costs nothing; a later one makes the DAC repeat its
last sample for the gap (an underrun, counted).  Commands act from the next
sample the DAC plays: the unplayed part of the buffer is regenerated.

The world's physics (the sinks) is instantaneous in a real lab but takes CPU time here: while
a tick's sinks run, the device's time stands still beyond :data:`WORLD_SHARE` of a tick, and
the CPU time they took beyond that share is time the device did not live (the planar plant's
slips of several parts): nothing the amplifier reports (step counter, moving) runs ahead of
the plant a camera sees.  The whole simulated device then runs slower than the wall clock,
but consistently; time the tick thread waited for the CPU the DAC plays through, as it would.

Each axis (:class:`~firmware_sim.axis.Axis`) has a DDS and an output chain that
enforces the amplifier's limits on the DAC codes; faults and refusals:
:mod:`firmware_sim.faults`.

Thread safety: one lock per :class:`Firmware`; every :class:`~firmware_sim.axis.Axis`
method and the tick take it, so any number of front ends (console, CANopen) may call
the API from their own threads.  Refused values raise
:class:`~firmware_sim.faults.LimitError`, other refusals
:class:`~firmware_sim.faults.FirmwareError`; their ``str()`` is the console's
error line.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.stack import StackParameters
from firmware_sim.axis import DAC_MAX_CODE, Axis
from firmware_sim.clock import Clock
from firmware_sim.faults import Fault, FirmwareError

DEFAULT_LOAD_CAPACITANCE_F = StackParameters().capacitance_f
DEFAULT_DAC_BUFFER_S = 0.100
"""Deep enough for a busy shared machine; it costs no command latency, because
commands regenerate the buffer from the sample the DAC plays when they arrive."""
WORLD_SHARE = 0.5
"""Fraction of a tick period the world's physics may take per tick (CPU time, and wall time
while it runs) before the device's time waits for it."""


@dataclass(frozen=True)
class FirmwareConfig:
    """Build-time settings of the firmware.

    axes: configured axes, numbered 1..axes; slots above (up to ``slots``) are empty.
    tick_hz: tick rate; sample_rate_hz: DAC rate (samples per tick = ratio, integer).
    dac_buffer_s: how far ahead of the DAC the tick keeps the buffer filled.
    watchdog_s: a tick later than this grounds every axis (WATCHDOG).
    host_watchdog_s: no host command for this long while moving → HOST_WATCHDOG; 0 = off.
    amplifier: rails, slew rate, current limit and frequency range (the shared
        model of :mod:`feeder.plant.amplifier`); load_capacitance_f: the stack
        capacitance the current limit is enforced for (nominal, F).
    """

    axes: int = 3
    slots: int = 7
    tick_hz: float = 1000.0
    sample_rate_hz: float = 100_000.0
    dac_buffer_s: float = DEFAULT_DAC_BUFFER_S
    watchdog_s: float = 0.25
    host_watchdog_s: float = 0.0
    amplifier: AmplifierLimits = field(default_factory=AmplifierLimits)
    load_capacitance_f: float = DEFAULT_LOAD_CAPACITANCE_F
    serial_number: str = "FS0001"

    @property
    def samples_per_tick(self) -> int:
        return round(self.sample_rate_hz / self.tick_hz)


@dataclass
class TickStats:
    """Timing of the tick loop; jitter = wake time − deadline, seconds."""

    ticks: int = 0
    late_ticks: int = 0
    missed_deadlines: int = 0
    underruns: int = 0
    underrun_samples: int = 0
    jitter_s: deque[float] = field(default_factory=lambda: deque(maxlen=100_000))

    def summary(self) -> dict[str, float | int]:
        """Counts and jitter p50/p99/max in seconds."""
        jitter = np.asarray(self.jitter_s, dtype=float)
        p50, p99, top = (
            (float(np.percentile(jitter, 50)), float(np.percentile(jitter, 99)), float(jitter.max()))
            if jitter.size
            else (0.0, 0.0, 0.0)
        )
        return {
            "ticks": self.ticks,
            "late_ticks": self.late_ticks,
            "missed_deadlines": self.missed_deadlines,
            "underruns": self.underruns,
            "underrun_samples": self.underrun_samples,
            "jitter_p50_s": p50,
            "jitter_p99_s": p99,
            "jitter_max_s": top,
        }


DacSink = Callable[[int, int, np.ndarray], None]
"""Called with (axis, index of the first sample, output volts per sample) for
every block of samples the DAC will play, in order."""

TickListener = Callable[[float], None]
"""Called at the end of every tick with the tick's time (s since start)."""


class Firmware:
    """The whole amplifier: axes 1..N, the tick loop and its statistics.

    ``Firmware(config)`` then ``axis(n)`` for the command API, ``add_sink`` to
    receive the DAC stream (the world, tests), and ``run(clock, stop_event)``
    in a thread (or ``run(VirtualClock(), max_ticks=k)`` inline) to tick.
    """

    def __init__(self, config: FirmwareConfig | None = None) -> None:
        self.config = config or FirmwareConfig()
        cfg = self.config
        if not 1 <= cfg.axes <= cfg.slots:
            raise ValueError(f"axes must be in 1..{cfg.slots}")
        if abs(cfg.sample_rate_hz / cfg.tick_hz - cfg.samples_per_tick) > 1e-9:
            raise ValueError("sample_rate_hz must be an integer multiple of tick_hz")
        self.lock = threading.Condition(threading.RLock())
        self.sample_rate = cfg.sample_rate_hz
        self.lsb_v = cfg.amplifier.max_amplitude_vpp / DAC_MAX_CODE
        self.max_slope_v_per_s = cfg.amplifier.max_slope_v_per_s(cfg.load_capacitance_f)
        self.max_codes_per_sample = max(
            1, math.floor(self.max_slope_v_per_s / cfg.sample_rate_hz / self.lsb_v)
        )
        self.buffer_samples = max(cfg.samples_per_tick, round(cfg.dac_buffer_s * cfg.sample_rate_hz))
        self.samples_played = 0
        self.stats = TickStats()
        self.stopped = False
        self._axes = {n: Axis(self, n) for n in range(1, cfg.axes + 1)}
        self._sinks: list[DacSink] = []
        self._tick_listeners: list[TickListener] = []
        self._last_host_s = 0.0
        self._now_s = 0.0
        self._tick_index = 0
        self._epoch_s: float | None = None  # clock time of the first tick: the DAC starts there
        self._clock: Clock | None = None  # the tick loop's clock, once it runs
        self._paused_s = 0.0  # clock time the device stood still while the world caught up
        self._world_since: float | None = None  # clock time the running sinks started

    def axis(self, number: int) -> Axis:
        """Axis ``number`` (1-based); empty or non-existent slots raise FirmwareError."""
        if number in self._axes:
            return self._axes[number]
        if 1 <= number <= self.config.slots:
            raise FirmwareError(f"No axis in slot {number}")
        raise FirmwareError(f"Axis number out of range: {number}")

    @property
    def axis_numbers(self) -> tuple[int, ...]:
        return tuple(self._axes)

    def add_sink(self, sink: DacSink) -> None:
        """Receive every block of DAC output the DAC played (called from the tick thread)."""
        with self.lock:
            self._sinks.append(sink)

    def add_tick_listener(self, listener: TickListener) -> None:
        """Call ``listener(now_s)`` at the end of every tick (from the tick thread)."""
        with self.lock:
            self._tick_listeners.append(listener)

    def host_activity(self) -> None:
        """A front end received a command from the host (kicks the host watchdog)."""
        with self.lock:
            self._last_host_s = self._now_s

    def ground_all(self) -> None:
        """Stop and ground every axis."""
        with self.lock:
            for axis in self._axes.values():
                axis.ground()

    def command_sample(self) -> int:
        """Index of the sample the DAC plays now, where a command takes effect (lock held).

        Between two ticks the DAC goes on playing its buffer, so a command that arrives
        0.3 ms after a tick acts 30 samples (at 100 kS/s) after that tick's sample, and two
        commands 0.3 ms apart act 0.3 ms apart, as on a real amplifier.  Before the loop
        runs, and under a virtual clock (which stands at the last tick), it is the last
        tick's sample.
        """
        if self._clock is None or self._epoch_s is None:
            return self.samples_played
        return max(self.samples_played, self._sample_at(self._device_time_s()))

    def _device_time_s(self) -> float:
        """The device's time now (s since its first tick, lock held): the clock's, less the time
        it stood still while the world's physics took more than its share of a tick."""
        assert self._clock is not None and self._epoch_s is not None
        now = self._clock.now_s()
        if self._world_since is not None:  # the sinks run: the device waits beyond the share
            now = min(now, self._world_since + WORLD_SHARE / self.config.tick_hz)
        return now - self._epoch_s - self._paused_s

    def _sample_at(self, t_s: float) -> int:
        """Index of the sample the DAC plays at ``t_s`` (s since its start)."""
        return int(t_s * self.sample_rate + 1e-6)

    def tick(self, now_s: float) -> None:
        """One tick at time ``now_s``.

        The samples the DAC played since the last tick go to the sinks (the
        world); then the buffer is topped up to ``dac_buffer_s`` ahead.  If the
        DAC ran dry it held its last sample for the gap (an underrun).  Sinks and
        tick listeners run after the lock is released, so the front ends wait
        only for the firmware's own work, not for the world's.
        """
        blocks: list[tuple[int, int, np.ndarray]] = []
        with self.lock:
            self._now_s = now_s
            cfg = self.config
            played = self._sample_at(now_s)
            if played > self.samples_played:
                axes = list(self._axes.values())
                if any(axis._written < played for axis in axes):
                    self.stats.underruns += 1
                    self.stats.underrun_samples += played - min(a._written for a in axes)
                for number, axis in self._axes.items():
                    if axis._written < played:
                        axis._hold(played - axis._written)
                    codes = axis._play(played - self.samples_played)
                    blocks.append((number, self.samples_played, cfg.amplifier.v_min_v + codes * self.lsb_v))
                self.samples_played = played
            if cfg.host_watchdog_s > 0 and now_s - self._last_host_s > cfg.host_watchdog_s:
                for axis in self._axes.values():
                    if axis._remaining != 0:
                        axis._latch(Fault.HOST_WATCHDOG)
            for axis in self._axes.values():
                n = played + self.buffer_samples - axis._written
                if n > 0:
                    axis._fill(n)
            self.lock.notify_all()  # waiters on played samples (wait_idle)
            sinks, listeners = list(self._sinks), list(self._tick_listeners)
            clock = self._clock if self._clock is not None and self._clock.realtime else None
            if clock is not None:
                self._world_since, work_from = clock.now_s(), clock.work_s()
        for number, first, volts in blocks:
            for sink in sinks:
                sink(number, first, volts)
        for listener in listeners:
            listener(now_s)
        if clock is not None:
            with self.lock:
                self._paused_s += max(0.0, clock.work_s() - work_from - WORLD_SHARE / self.config.tick_hz)
                self._world_since = None

    def volts(self, code: int) -> float:
        """Output voltage of a DAC code."""
        return self.config.amplifier.v_min_v + code * self.lsb_v

    def run(self, clock: Clock, stop: threading.Event | None = None, max_ticks: int | None = None) -> None:
        """Tick at ``tick_hz`` on ``clock`` until ``stop`` is set or ``max_ticks`` ran.

        Call again with the same clock to continue.  Jitter (wake − deadline) is
        recorded per tick; a tick more than one period late is a late tick, and
        deadlines it slept through are skipped (the DAC buffer covers them).  A
        wake later than ``watchdog_s`` latches WATCHDOG on every axis.  Deadlines and
        the DAC's time are the device's: the clock's, less the time it stood still
        for the world (module docstring).
        """
        period = 1.0 / self.config.tick_hz
        done = 0
        with self.lock:
            self._clock = clock
        while not (stop is not None and stop.is_set()) and (max_ticks is None or done < max_ticks):
            deadline = self._tick_index * period + self._paused_s
            now = clock.sleep_until(deadline)
            late = now - deadline
            with self.lock:
                self.stats.ticks += 1
                self.stats.jitter_s.append(late)
                if late > period:
                    self.stats.late_ticks += 1
                if late > self.config.watchdog_s:
                    for axis in self._axes.values():
                        axis._latch(Fault.WATCHDOG)
            if self._epoch_s is None:
                self._epoch_s = now
            self.tick(now - self._epoch_s - self._paused_s)
            with self.lock:
                self._tick_index += 1
                if clock.realtime and now - self._paused_s >= self._tick_index * period:
                    skipped = math.floor((now - self._paused_s) / period) + 1 - self._tick_index
                    self.stats.missed_deadlines += skipped
                    self._tick_index += skipped
            done += 1

    def tick_summary(self) -> dict[str, float | int]:
        """The tick loop's statistics (see :class:`TickStats`), and ``world_wait_s``: how long
        the device's time stood still for its world (module docstring)."""
        with self.lock:
            return {**self.stats.summary(), "world_wait_s": self._paused_s}

    def shutdown(self) -> None:
        """Ground every axis and wake anyone waiting for an axis."""
        with self.lock:
            for axis in self._axes.values():
                axis.ground()
            self.stopped = True
            self.lock.notify_all()
