"""The amplifier's firmware: tick loop, DDS, DAC buffer, output limits, safety.

Embedded style (DESIGN §6).  A fixed-period tick (default 1 kHz) hands the
samples the DAC played since the previous tick to the sinks (the world's
plant, test recorders) and tops up each axis' DAC buffer to ``dac_buffer_s``
(default 100 ms) ahead of the DAC's read pointer, the way a DMA ring in
circular mode with half-transfer interrupts is fed.  A tick that comes late by
less than the buffer depth costs nothing; a later one makes the DAC repeat its
last sample for the gap (an underrun, counted).  Commands act from the next
sample the DAC plays: the unplayed part of the buffer is regenerated.

Each axis has a DDS: a 32-bit phase accumulator advanced by ``round(f·2³²/f_s)``
per sample whose top bits index the axis' wavetable, with linear interpolation
between entries: the flyback design's 4096-point 16-bit table, or after
``setpu``/``setpd`` the ANC300's 256-point pattern (values 0–255).  A period
of the pattern is one step: the step counter changes when the DAC plays the
sample that completes a period.

Output chain per sample:  pattern × amplitude (± offset, by mode) → clamp to
the rails → 16-bit DAC code → slew limit in DAC codes, the step per sample
bounded by ``min(slew, I_max/C)/f_s`` (current into the stack capacitance,
I = C·dV/dt, :meth:`feeder.plant.amplifier.AmplifierLimits.max_slope_v_per_s`).
The limits are enforced on the integer code stream, so they hold exactly on
what the DAC plays.

Safety state machine per axis: a latched ``fault_word`` (see :class:`Fault`);
any fault grounds the axis and stops it; stepping modes are refused until
:meth:`Axis.clear_faults`.  Faults: ``WATCHDOG`` (the tick loop stalled longer
than ``watchdog_s``), ``HOST_WATCHDOG`` (no host command for
``host_watchdog_s`` while an axis moves; off by default), ``OVERTEMP``
(injected by the host, for tests).  An underrun is counted, not a fault: the
held sample is a constant, safe output.

Thread safety: one lock per :class:`Firmware`; every :class:`Axis` method and
the tick take it, so any number of front ends (console, CANopen) may call
the API from their own threads.  Refused values raise :class:`LimitError`,
other refusals :class:`FirmwareError`; their ``str()`` is the console's
error line.
"""

from __future__ import annotations

import enum
import math
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.stack import StackParameters
from feeder.protocol.anc300 import (
    FAULT_BITS,
    MODES,
    PATTERN_MAX,
    PATTERN_POINTS,
    STEPPING_MODES,
    fault_names,
)
from feeder.waveform import FLYBACK_SHAPES, Waveform
from firmware_sim.clock import Clock

WAVETABLE_POINTS = 4096
DAC_BITS = 16
DAC_MAX_CODE = (1 << DAC_BITS) - 1
PHASE_BITS = 32
MAX_STEPS = (1 << 31) - 1
CAPACITANCE_MEASURE_S = 0.1
DEFAULT_LOAD_CAPACITANCE_F = StackParameters().capacitance_f
DEFAULT_DAC_BUFFER_S = 0.100
"""Deep enough for a busy shared machine; it costs no command latency, because
commands regenerate the unplayed part of the buffer."""


class FirmwareError(Exception):
    """A command the firmware refuses; ``str()`` is the console's error line."""


class LimitError(FirmwareError):
    """A value outside its allowed range ``[lo, hi]``."""

    def __init__(self, field: str, value: float, lo: float, hi: float) -> None:
        super().__init__(f"Value out of range: {field} = {_plain(value)} not in [{_plain(lo)}, {_plain(hi)}]")
        self.field = field
        self.value = value
        self.lo = lo
        self.hi = hi


def _plain(value: float) -> str:
    """A number in plain fixed point (no exponent), trailing zeros dropped."""
    if not (math.isfinite(value) and abs(value) < 1e15):
        return "(too large)"
    return f"{value:.9f}".rstrip("0").rstrip(".")


class Fault(enum.IntFlag):
    """Bits of an axis' latched fault word (0 = healthy)."""

    WATCHDOG = 0x01
    HOST_WATCHDOG = 0x02
    OVERTEMP = 0x04


assert {f.name.lower(): int(f) for f in Fault if f.name} == FAULT_BITS, "Fault drifted from the protocol"
REARMABLE_FAULTS = int(Fault.WATCHDOG | Fault.HOST_WATCHDOG)
"""Faults a stepping ``setm`` clears (the stall is over once the host commands again)."""


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


@dataclass(frozen=True)
class AxisStatus:
    """Snapshot of one axis (what ``status()`` and the console's ``getst`` report)."""

    axis: int
    mode: str
    frequency_hz: float
    amplitude_v: float
    offset_v: float
    flyback_shape: str
    flyback_s: float
    step_counter: int
    moving: bool
    fault_word: int
    output_v: float

    @property
    def faults(self) -> tuple[str, ...]:
        return fault_names(self.fault_word)


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


def sawtooth_design(
    shape: str, flyback_s: float, frequency_hz: float, direction: str = "forward"
) -> Waveform:
    """The sawtooth design (unit amplitude) behind an axis' flyback settings."""
    return Waveform(
        frequency_hz=frequency_hz,
        amplitude_vpp=1.0,
        flyback_shape=shape,
        flyback_s=flyback_s if shape != "current-limited" else None,
        direction=direction,
    )


class Axis:
    """One output channel: DDS, pattern tables, mode, step counter, faults.

    Obtain with :meth:`Firmware.axis`; all methods are thread-safe.
    """

    def __init__(self, firmware: Firmware, number: int) -> None:
        self._fw = firmware
        self.number = number
        self._mode = "gnd"
        self._frequency_hz = 100.0
        self._amplitude_v = 0.0
        self._offset_v = 0.0
        self._flyback_shape = "current-limited"
        self._flyback_s = 0.0
        self._patterns: dict[bool, list[int]] = {}  # 256-point 0–255 (getpu/setpu)
        self._tables: dict[bool, np.ndarray] = {}  # what the DDS reads, 0..1
        self._update_patterns()
        self._phase = 0
        self._up = True
        self._remaining = 0  # steps left in the burst; -1 = continuous
        self._step_counter = 0  # steps the DAC has played
        self._fault_word = 0
        self._code = 0  # last DAC code generated (the slew limiter's state)
        self._played_code = 0  # last DAC code played
        self._written = 0  # index of the next sample to generate
        self._pending_codes = np.zeros(0, dtype=np.int64)  # generated, not yet played
        self._pending_steps = np.zeros(0, dtype=np.int64)  # ±1 where a period completes
        self._pending_phases = np.zeros(0, dtype=np.uint64)  # DDS phase of each sample
        self._cap_done_sample = 0  # capacitance measurement ends at this sample
        self._active_until = 0  # the last burst's final sample plays before this one
        self._capacitance_f = firmware.config.load_capacitance_f

    # -- settings -------------------------------------------------------------

    def set_mode(self, mode: str) -> None:
        """Select ``gnd``, ``inp``, ``cap``, ``stp``, ``off``, ``stp+`` or ``stp-``.

        Leaving a stepping mode stops any motion; ``cap`` measures the load
        capacitance for 0.1 s and then returns to ``gnd``.  Selecting a stepping
        mode re-arms an axis grounded by a watchdog (a transient stall: the host's
        explicit command is the reset, so a host speaking only a real ANC300's
        verbs can recover); any other latched fault still refuses it.
        """
        with self._fw.lock:
            if mode not in MODES:
                raise FirmwareError("Unknown mode")
            if mode in STEPPING_MODES and not self._fault_word & ~REARMABLE_FAULTS:
                self._fault_word = 0
            if mode != "gnd" and self._fault_word:
                raise FirmwareError("Axis in fault state")
            if mode == "cap":
                self._cap_done_sample = self._fw.samples_played + round(
                    CAPACITANCE_MEASURE_S * self._fw.sample_rate
                )
            if mode not in STEPPING_MODES:
                self._remaining = 0
            self._mode = mode
            self._rewrite(resume=mode in STEPPING_MODES)

    def set_frequency(self, hz: float) -> None:
        """Step (sawtooth) frequency within the amplifier's range; the flyback pattern follows."""
        with self._fw.lock:
            amp = self._fw.config.amplifier
            _check("frequency", hz, amp.min_frequency_hz, amp.max_frequency_hz)
            if self._flyback_shape != "custom":
                _check("flyback", self._flyback_s, 0.0, 1.0 / hz - 1.0 / self._fw.sample_rate)
            self._frequency_hz = float(hz)
            self._update_patterns()
            self._rewrite(resume=True)

    def set_amplitude(self, volts: float) -> None:
        """Peak-to-peak step amplitude, 0 … (v_max − v_min) volts."""
        with self._fw.lock:
            _check("voltage", volts, 0.0, self._fw.config.amplifier.max_amplitude_vpp)
            self._amplitude_v = float(volts)
            self._rewrite(resume=True)

    def set_offset(self, volts: float) -> None:
        """DC offset used in ``inp``, ``stp+`` and ``stp-``, within the rails (V)."""
        with self._fw.lock:
            amp = self._fw.config.amplifier
            _check("offset", volts, amp.v_min_v, amp.v_max_v)
            self._offset_v = float(volts)
            self._rewrite(resume=True)

    def set_flyback(self, shape: str, seconds: float) -> None:
        """Flyback shape (``linear``, ``half-cosine``, ``current-limited``) and time.

        ``seconds`` is the flyback duration for ``linear``/``half-cosine`` (more
        than one DAC sample, less than a period); it is ignored for
        ``current-limited``, where the current limit into the stack sets it.
        Rebuilds both patterns.
        """
        with self._fw.lock:
            if shape not in FLYBACK_SHAPES:
                raise FirmwareError("Unknown flyback shape")
            if shape == "current-limited":
                seconds = 0.0
            else:
                _check(
                    "flyback",
                    seconds,
                    1.0 / self._fw.sample_rate,
                    1.0 / self._frequency_hz - 1.0 / self._fw.sample_rate,
                )
            self._flyback_shape = shape
            self._flyback_s = float(seconds)
            self._update_patterns()
            self._rewrite(resume=True)

    def set_pattern(self, up: bool, values: Sequence[int]) -> None:
        """Load a 256-point pattern (0–255) for up (``setpu``) or down (``setpd``) steps."""
        with self._fw.lock:
            if len(values) != PATTERN_POINTS:
                raise FirmwareError(f"Pattern needs {PATTERN_POINTS} values, got {len(values)}")
            for v in values:
                _check("pattern", v, 0, PATTERN_MAX)
            self._patterns[up] = [int(v) for v in values]
            self._tables[up] = np.asarray(values, dtype=float) / PATTERN_MAX
            self._flyback_shape = "custom"
            self._flyback_s = 0.0
            self._rewrite(resume=True)

    def pattern(self, up: bool) -> list[int]:
        """The 256-point pattern for up (True) or down steps."""
        with self._fw.lock:
            return list(self._patterns[up])

    # -- motion ---------------------------------------------------------------

    def step(self, count: int) -> None:
        """Start a burst of ``|count|`` steps, up (+) or down (−); returns at once."""
        with self._fw.lock:
            if count == 0:
                raise FirmwareError("Step count must not be 0")
            _check("steps", abs(count), 1, MAX_STEPS)
            self._start(up=count > 0, remaining=abs(int(count)))

    def run_continuous(self, up: bool) -> None:
        """Step up (True) or down until :meth:`stop`."""
        with self._fw.lock:
            self._start(up=up, remaining=-1)

    def stop(self) -> None:
        """Stop stepping at once: the DDS phase (and output) freezes at the next sample."""
        with self._fw.lock:
            self._remaining = 0
            self._rewrite(resume=False)

    def ground(self) -> None:
        """Stop and ground the output (the safe state) from the next sample on."""
        with self._fw.lock:
            self._remaining = 0
            self._mode = "gnd"
            self._rewrite(resume=False)

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Block until the DAC has played the burst and no capacitance measurement
        runs; False on timeout."""
        with self._fw.lock:
            return self._fw.lock.wait_for(lambda: not self._busy() or self._fw.stopped, timeout_s)

    # -- faults ---------------------------------------------------------------

    def inject_fault(self, bit: Fault) -> None:
        """Latch ``bit`` (host test hook): the axis grounds and stops."""
        with self._fw.lock:
            self._latch(bit)

    def clear_faults(self) -> None:
        """Clear the fault word; the axis stays grounded until the host selects a mode."""
        with self._fw.lock:
            self._fault_word = 0

    # -- readback -------------------------------------------------------------

    @property
    def capacitance_f(self) -> float:
        """Last measured load capacitance, F."""
        with self._fw.lock:
            return self._capacitance_f

    def status(self) -> AxisStatus:
        with self._fw.lock:
            return AxisStatus(
                axis=self.number,
                mode=self._mode,
                frequency_hz=self._frequency_hz,
                amplitude_v=self._amplitude_v,
                offset_v=self._offset_v,
                flyback_shape=self._flyback_shape,
                flyback_s=self._flyback_s,
                step_counter=self._step_counter,
                moving=self._busy() and self._mode != "cap",
                fault_word=self._fault_word,
                output_v=self._fw.volts(self._played_code),
            )

    # -- internals (called with the lock held) --------------------------------

    def _busy(self) -> bool:
        return self._remaining != 0 or self._mode == "cap" or self._fw.samples_played < self._active_until

    def _rewrite(self, resume: bool) -> None:
        """Regenerate the unplayed part of the DAC buffer from the current state, so
        that every command acts from the next sample the DAC plays.

        The DDS restarts from the phase of the first unplayed sample; with
        ``resume`` a burst in progress keeps the steps it has not played yet.
        """
        played = self._fw.samples_played
        n = self._written - played
        if n <= 0:
            return
        if self._pending_phases.size:
            self._phase = int(self._pending_phases[0])
            if resume and self._remaining >= 0 and self._active_until > played:
                self._remaining += int(np.abs(self._pending_steps).sum())
        self._active_until = min(self._active_until, played)
        self._code = self._played_code
        self._written = self._fw.samples_played
        self._pending_codes = self._pending_codes[:0]
        self._pending_steps = self._pending_steps[:0]
        self._pending_phases = self._pending_phases[:0]
        self._fill(n)
        self._fw.lock.notify_all()

    def _fill(self, n: int) -> None:
        """Generate the next ``n`` samples into the DAC buffer."""
        codes, steps, phases = self._generate(self._written, n)
        self._pending_codes = np.concatenate((self._pending_codes, codes))
        self._pending_steps = np.concatenate((self._pending_steps, steps))
        self._pending_phases = np.concatenate((self._pending_phases, phases))
        self._written += n

    def _hold(self, n: int) -> None:
        """The DAC ran dry for ``n`` samples: it repeated its last code."""
        self._pending_codes = np.concatenate((self._pending_codes, np.full(n, self._code, dtype=np.int64)))
        self._pending_steps = np.concatenate((self._pending_steps, np.zeros(n, dtype=np.int64)))
        self._pending_phases = np.concatenate(
            (self._pending_phases, np.full(n, self._phase, dtype=np.uint64))
        )
        self._written += n

    def _play(self, n: int) -> np.ndarray:
        """The next ``n`` buffered codes leave for the DAC; the step counter follows."""
        codes = self._pending_codes[:n]
        self._step_counter += int(self._pending_steps[:n].sum())
        self._played_code = int(codes[-1])
        self._pending_codes = self._pending_codes[n:]
        self._pending_steps = self._pending_steps[n:]
        self._pending_phases = self._pending_phases[n:]
        return codes

    def _start(self, up: bool, remaining: int) -> None:
        if self._mode not in STEPPING_MODES:
            raise FirmwareError("Axis in wrong mode")
        if self._fault_word:
            raise FirmwareError("Axis in fault state")
        self._remaining = 0
        self._rewrite(resume=False)  # the phase where the DAC is now
        self._up = up
        self._remaining = remaining
        self._rewrite(resume=False)

    def _latch(self, bit: Fault) -> None:
        self._fault_word |= int(bit)
        self._remaining = 0
        self._mode = "gnd"
        self._rewrite(resume=False)

    def _update_patterns(self) -> None:
        """Rebuild both patterns from the flyback design (not after setpu/setpd).

        The DDS reads the design's 4096-point 16-bit table (``Waveform.dac_table``);
        the ANC300's 8-bit 256-point tables would put a slope change on the ramp
        at every rounding step, enough to shake a part loose at low amplitude.
        """
        if self._flyback_shape == "custom":
            return
        design = sawtooth_design(self._flyback_shape, self._flyback_s, self._frequency_hz)
        up, down = design.anc300_tables()
        self._patterns = {True: up, False: down}
        self._tables = {
            forward: sawtooth_design(
                self._flyback_shape, self._flyback_s, self._frequency_hz, "forward" if forward else "backward"
            )
            .dac_table(WAVETABLE_POINTS, DAC_BITS)
            .astype(float)
            / DAC_MAX_CODE
            for forward in (True, False)
        }

    def _generate(self, first_sample: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The next ``n`` DAC codes, signed step marks and DDS phases."""
        fw = self._fw
        amp = fw.config.amplifier
        if self._mode == "cap" and first_sample >= self._cap_done_sample:
            self._mode = "gnd"
            fw.lock.notify_all()
        if self._mode in STEPPING_MODES:
            wave, steps, phases = self._dds(first_sample, n)
            if self._mode == "stp":
                volts = self._amplitude_v * wave
            elif self._mode == "stp+":
                volts = self._offset_v + self._amplitude_v * wave
            else:
                volts = self._offset_v - self._amplitude_v * wave
        else:
            steps = np.zeros(n, dtype=np.int64)
            phases = np.full(n, self._phase, dtype=np.uint64)
            level = self._offset_v if self._mode == "inp" else 0.0  # gnd, off, cap: 0 V
            code = round((min(max(level, amp.v_min_v), amp.v_max_v) - amp.v_min_v) / fw.lsb_v)
            if code == self._code:  # at rest: nothing to limit
                return np.full(n, code, dtype=np.int64), steps, phases
            volts = np.full(n, level)
        target = np.rint((np.clip(volts, amp.v_min_v, amp.v_max_v) - amp.v_min_v) / fw.lsb_v).astype(np.int64)
        codes = _slew_limit(target, self._code, fw.max_codes_per_sample)
        self._code = int(codes[-1])
        return codes, steps, phases

    def _dds(self, first_sample: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pattern value (0..1), signed step marks (±1 on the sample that completes a
        period) and phase of the next ``n`` samples."""
        table = self._tables[self._up]
        mask = np.uint64((1 << PHASE_BITS) - 1)
        if self._remaining == 0:
            phases = np.full(n, self._phase, dtype=np.uint64)
            return _lookup(table, phases), np.zeros(n, dtype=np.int64), phases
        increment = round(self._frequency_hz * (1 << PHASE_BITS) / self._fw.sample_rate)
        raw = self._phase + increment * np.arange(n + 1, dtype=np.uint64)
        wraps = (raw >> np.uint64(PHASE_BITS)).astype(np.int64)  # periods completed before k
        limit = self._remaining if self._remaining > 0 else int(wraps[-1]) + 1
        marks = np.diff(np.minimum(wraps, limit))
        done = wraps[:-1] >= limit  # past the burst's last period: hold its start
        phases = np.where(done, np.uint64(0), raw[:-1] & mask)
        self._active_until = first_sample + (int(np.argmax(done)) if done.any() else n)
        if self._remaining > 0 and wraps[-1] >= self._remaining:
            self._phase = 0
            self._remaining = 0
            self._fw.lock.notify_all()
        else:
            self._phase = int(raw[-1] & mask)
            if self._remaining > 0:
                self._remaining -= int(wraps[-1])
        return _lookup(table, phases), marks if self._up else -marks, phases


def _lookup(table: np.ndarray, phases: np.ndarray) -> np.ndarray:
    """Linear interpolation of a cyclic 2**k-point table at 32-bit phases (top k bits index)."""
    shift = PHASE_BITS - (table.size.bit_length() - 1)
    index = (phases >> np.uint64(shift)).astype(np.int64)
    frac = (phases & np.uint64((1 << shift) - 1)).astype(float) / (1 << shift)
    here = table[index]
    return here + (table[(index + 1) % table.size] - here) * frac


def _slew_limit(target: np.ndarray, start: int, max_step: int) -> np.ndarray:
    """Codes that follow ``target`` from ``start`` moving at most ``max_step`` per sample.

    Spans that follow the target are found vectorised; only the limited runs
    (flybacks, jumps) are stepped sample by sample until they meet the target.
    """
    out = target.copy()
    code = start
    i = 0
    n = target.size
    while i < n:
        previous = np.concatenate(([code], target[i : n - 1]))
        jumps = np.flatnonzero(np.abs(target[i:] - previous) > max_step)
        if not jumps.size:
            break
        j = i + int(jumps[0])
        code = int(out[j - 1]) if j > 0 else start
        while j < n:
            want = int(target[j])
            code += max(-max_step, min(max_step, want - code))
            out[j] = code
            j += 1
            if code == want:
                break
        i = j
    return out


def _check(name: str, value: float, lo: float, hi: float) -> None:
    if not (math.isfinite(value) and lo <= value <= hi):
        raise LimitError(name, value, lo, hi)


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
            played = int(now_s * self.sample_rate + 1e-6)
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
        for number, first, volts in blocks:
            for sink in sinks:
                sink(number, first, volts)
        for listener in listeners:
            listener(now_s)

    def volts(self, code: int) -> float:
        """Output voltage of a DAC code."""
        return self.config.amplifier.v_min_v + code * self.lsb_v

    def run(self, clock: Clock, stop: threading.Event | None = None, max_ticks: int | None = None) -> None:
        """Tick at ``tick_hz`` on ``clock`` until ``stop`` is set or ``max_ticks`` ran.

        Call again with the same clock to continue.  Jitter (wake − deadline) is
        recorded per tick; a tick more than one period late is a late tick, and
        deadlines it slept through are skipped (the DAC buffer covers them).  A
        wake later than ``watchdog_s`` latches WATCHDOG on every axis.
        """
        period = 1.0 / self.config.tick_hz
        done = 0
        while not (stop is not None and stop.is_set()) and (max_ticks is None or done < max_ticks):
            deadline = self._tick_index * period
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
            self.tick(now - self._epoch_s)
            with self.lock:
                self._tick_index += 1
                if clock.realtime and now >= self._tick_index * period:
                    skipped = math.floor(now / period) + 1 - self._tick_index
                    self.stats.missed_deadlines += skipped
                    self._tick_index += skipped
            done += 1

    def tick_summary(self) -> dict[str, float | int]:
        """The tick loop's statistics (see :class:`TickStats`)."""
        with self.lock:
            return self.stats.summary()

    def shutdown(self) -> None:
        """Ground every axis and wake anyone waiting for an axis."""
        with self.lock:
            for axis in self._axes.values():
                axis.ground()
            self.stopped = True
            self.lock.notify_all()
