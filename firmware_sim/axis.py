"""One amplifier output channel of the firmware: DDS, DAC buffer, output limits.

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

The DAC buffer of an axis is what :class:`firmware_sim.firmware.Firmware`'s tick
tops up and plays (see there); faults: :mod:`firmware_sim.faults`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from feeder.protocol.anc300 import MODES, PATTERN_MAX, PATTERN_POINTS, STEPPING_MODES, fault_names
from feeder.waveform import FLYBACK_SHAPES, Waveform
from firmware_sim.dac_buffer import DacBuffer
from firmware_sim.faults import REARMABLE_FAULTS, Fault, FirmwareError, LimitError

if TYPE_CHECKING:
    from firmware_sim.firmware import Firmware

WAVETABLE_POINTS = 4096
DAC_BITS = 16
DAC_MAX_CODE = (1 << DAC_BITS) - 1
PHASE_BITS = 32
MAX_STEPS = (1 << 31) - 1
CAPACITANCE_MEASURE_S = 0.1


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

    Obtain with :meth:`firmware_sim.firmware.Firmware.axis`; all methods are thread-safe.
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
        self._pending = DacBuffer()  # generated, not yet played
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
                self._cap_done_sample = self._fw.command_sample() + round(
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
        """DC offset played in ``off`` (alone) and ``stp+``/``stp-`` (under the steps), in the rails (V)."""
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
        runs; False on timeout.

        Continuous motion never ends by itself: FirmwareError at once, or as soon as
        another front end starts it during the wait.  ``stop`` or a non-stepping mode
        from another front end ends the wait (the axis is idle then).
        """
        with self._fw.lock:
            idle = self._fw.lock.wait_for(
                lambda: not self._busy(self._fw.command_sample()) or self._fw.stopped or self._remaining < 0,
                timeout_s,
            )
            if self._remaining < 0:
                raise FirmwareError("Axis in continuous motion")
            return idle

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
        """The axis as of now: the steps and output of the samples the DAC has played by the
        time of the call (it plays on between ticks)."""
        with self._fw.lock:
            now = self._fw.command_sample()  # one instant: the DAC plays on while this is taken
            played = self._played_since_tick(now)
            code = int(self._pending.codes[played - 1]) if played else self._played_code
            return AxisStatus(
                axis=self.number,
                mode=self._mode,
                frequency_hz=self._frequency_hz,
                amplitude_v=self._amplitude_v,
                offset_v=self._offset_v,
                flyback_shape=self._flyback_shape,
                flyback_s=self._flyback_s,
                step_counter=self._step_counter + int(self._pending.steps[:played].sum()),
                moving=self._busy(now) and self._mode != "cap",
                fault_word=self._fault_word,
                output_v=self._fw.volts(code),
            )

    # -- internals (called with the lock held) --------------------------------

    def _played_since_tick(self, now: int) -> int:
        """How many buffered samples the DAC has played since the last tick by sample ``now``
        (it plays on between ticks; at most what was buffered)."""
        return min(now, self._written) - self._fw.samples_played

    def _busy(self, now: int) -> bool:
        """Whether the axis is busy at sample ``now`` (a burst a command ended is over from
        that command's sample)."""
        return self._remaining != 0 or self._mode == "cap" or now < self._active_until

    def _rewrite(self, resume: bool, at: int | None = None) -> None:
        """Regenerate the DAC buffer from the current state, from the sample ``at`` (default:
        the one the DAC plays when the command arrives, ``Firmware.command_sample``): every
        command acts from there, the samples before it play as they were generated.

        The DDS restarts from the phase of the first regenerated sample; with ``resume``
        a burst in progress keeps the steps it has not played yet.
        """
        # buffered samples the DAC plays before the command acts
        kept = self._played_since_tick(self._fw.command_sample() if at is None else at)
        start = self._fw.samples_played + kept
        n = self._written - start
        if n <= 0:
            return
        self._phase = int(self._pending.phases[kept])
        if resume and self._remaining >= 0 and self._active_until > start:
            self._remaining += int(np.abs(self._pending.steps[kept:]).sum())
        self._active_until = min(self._active_until, start)
        self._code = int(self._pending.codes[kept - 1]) if kept else self._played_code
        self._written = start
        self._pending.keep(kept)
        self._fill(n)
        self._fw.lock.notify_all()

    def _fill(self, n: int) -> None:
        """Generate the next ``n`` samples into the DAC buffer."""
        generated = self._generate(self._written, n)
        if generated is None:
            self._pending.hold(n, self._code, self._phase)
        else:
            self._pending.append(*generated)
        self._written += n

    def _hold(self, n: int) -> None:
        """The DAC ran dry for ``n`` samples: it repeated its last code."""
        self._pending.hold(n, self._code, self._phase)
        self._written += n

    def _play(self, n: int) -> np.ndarray:
        """The next ``n`` buffered codes leave for the DAC; the step counter follows."""
        codes, steps = self._pending.take(n)
        self._step_counter += int(steps.sum())
        self._played_code = int(codes[-1])
        return codes

    def _start(self, up: bool, remaining: int) -> None:
        if self._mode not in STEPPING_MODES:
            raise FirmwareError("Axis in wrong mode")
        if self._fault_word:
            raise FirmwareError("Axis in fault state")
        # both regenerations act from the sample of the command's arrival: the first one's
        # work (~3 ms of 100 ms of samples) must not delay the burst
        at = self._fw.command_sample()
        self._remaining = 0
        self._rewrite(resume=False, at=at)  # the phase where the DAC is then
        self._up = up
        self._remaining = remaining
        self._rewrite(resume=False, at=at)

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

    def _generate(self, first_sample: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The next ``n`` DAC codes, signed step marks and DDS phases; None when the axis rests
        at its code (the DDS phase held, no steps)."""
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
            # off: the offset alone (ANC300 offset mode); gnd, cap: 0 V; inp: the AC-IN/DC-IN
            # inputs only, which nothing drives here: 0 V
            level = self._offset_v if self._mode == "off" else 0.0
            code = round((min(max(level, amp.v_min_v), amp.v_max_v) - amp.v_min_v) / fw.lsb_v)
            if code == self._code:  # at rest: nothing to limit
                return None
            steps = np.zeros(n, dtype=np.int64)
            phases = np.full(n, self._phase, dtype=np.uint64)
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
