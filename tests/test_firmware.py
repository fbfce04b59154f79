"""Firmware core in virtual time: DDS, step counting, DAC limits, safety state machine."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from feeder.plant.amplifier import AmplifierLimits
from feeder.waveform import Waveform
from firmware_sim.axis import Axis, _slew_limit
from firmware_sim.clock import VirtualClock
from firmware_sim.faults import Fault, FirmwareError, LimitError
from firmware_sim.firmware import Firmware, FirmwareConfig


class Recorder:
    """Collects the DAC stream per axis and checks that blocks are contiguous."""

    def __init__(self, firmware: Firmware) -> None:
        self.blocks: dict[int, list[np.ndarray]] = {}
        self.next_index: dict[int, int] = {}
        firmware.add_sink(self)

    def __call__(self, axis: int, first: int, volts: np.ndarray) -> None:
        assert self.next_index.get(axis, 0) == first
        self.next_index[axis] = first + volts.size
        self.blocks.setdefault(axis, []).append(volts.copy())

    def volts(self, axis: int = 1) -> np.ndarray:
        return np.concatenate(self.blocks[axis])


def make(**kwargs: object) -> tuple[Firmware, Recorder, VirtualClock]:
    fw = Firmware(FirmwareConfig(**kwargs))  # type: ignore[arg-type]
    return fw, Recorder(fw), VirtualClock()


def test_burst_of_n_steps_counts_n_and_lasts_n_periods() -> None:
    fw, rec, clock = make()
    axis = fw.axis(1)
    axis.set_frequency(250.0)
    axis.set_amplitude(100.0)
    axis.set_flyback("linear", 0.0004)  # slower than the current limit: the DAC follows it
    axis.set_mode("stp")
    axis.step(7)
    fw.run(clock, max_ticks=60)
    status = axis.status()
    assert status.step_counter == 7 and not status.moving
    v = rec.volts()
    # the output is at rest (0 V) before the burst and after it; it is busy for 7 periods
    busy = np.flatnonzero(v > 1e-9)
    duration = (busy[-1] + 1) / fw.sample_rate
    assert duration == pytest.approx(7 / 250.0, abs=2.0 / 250 / 256 + 2 / fw.sample_rate)
    axis.step(-3)
    fw.run(clock, max_ticks=40)
    assert axis.status().step_counter == 4


def play_continuous(fw: Firmware, rec: Recorder, clock: VirtualClock, ticks: int) -> np.ndarray:
    axis = fw.axis(1)
    axis.set_frequency(10.0)
    axis.set_amplitude(50.0)
    axis.set_mode("stp")
    axis.run_continuous(up=True)
    fw.run(clock, max_ticks=ticks)
    return rec.volts()


def test_dds_plays_the_flyback_design_times_amplitude() -> None:
    # 10 Hz: the ramp is far below every slope limit, so the DAC plays the design itself
    fw, rec, clock = make()
    fw.axis(1).set_frequency(10.0)
    fw.axis(1).set_flyback("half-cosine", 0.01)
    v = play_continuous(fw, rec, clock, 250)[:20000]
    design = Waveform(frequency_hz=10.0, amplitude_vpp=50.0, flyback_shape="half-cosine", flyback_s=0.01)
    expected = design.voltage_at_phase(np.arange(v.size) * 10.0 / fw.sample_rate)
    np.testing.assert_allclose(v, expected, atol=2 * fw.lsb_v)


def test_dds_after_setpu_plays_the_interpolated_8_bit_pattern() -> None:
    fw, rec, clock = make()
    table = [round(255 * (i / 255) ** 2) for i in range(256)]
    fw.axis(1).set_pattern(True, table)
    v = play_continuous(fw, rec, clock, 150)[:10000]
    cyclic = np.array([*table, table[0]], dtype=float) / 255
    phase = (np.arange(v.size) * 10.0 / fw.sample_rate) % 1.0
    expected = 50.0 * np.interp(phase * 256, np.arange(257), cyclic)
    np.testing.assert_allclose(v, expected, atol=fw.lsb_v + 50.0 * 256 * 1e-6)


def test_dac_stream_stays_within_rails_slew_and_current_limit() -> None:
    amp = AmplifierLimits(v_max_v=150.0, slew_rate_v_per_s=3e6, current_limit_a=0.2)
    fw, rec, clock = make(amplifier=amp, load_capacitance_f=1e-6)
    axis = fw.axis(1)
    axis.set_amplitude(150.0)
    axis.set_frequency(500.0)
    axis.set_mode("stp")
    axis.run_continuous(up=True)
    fw.run(clock, max_ticks=30)
    axis.set_mode("stp+")
    axis.set_offset(120.0)
    fw.run(clock, max_ticks=30)
    axis.ground()
    fw.run(clock, max_ticks=30)
    v = rec.volts()
    dt = 1.0 / fw.sample_rate
    assert v.min() >= 0.0 and v.max() <= 150.0
    current = 1e-6 * np.abs(np.diff(v)) / dt
    assert current.max() <= 0.2 * (1 + 1e-9)
    # the current limit binds: the 150 V flyback takes C·ΔV/I = 0.75 ms, not one sample
    assert current.max() > 0.19
    assert v[-1] == 0.0


@pytest.mark.parametrize(
    ("mode", "level_v"),
    [("off", 40.0), ("inp", 0.0), ("gnd", 0.0), ("stp", 0.0)],
)
def test_modes_play_the_offset_as_a_real_anc300_does(mode: str, level_v: float) -> None:
    """ANC300 manual, ``setm``: ``off`` is the offset mode (the ``seta`` voltage alone); ``inp``
    the AC-IN/DC-IN inputs alone (undriven here); ``stp`` turns an offset off; nothing steps."""
    fw, rec, clock = make()
    axis = fw.axis(1)
    axis.set_offset(40.0)
    axis.set_mode(mode)
    fw.run(clock, max_ticks=30)
    assert rec.volts()[-1] == pytest.approx(level_v, abs=fw.lsb_v)


def test_limits_refuse_with_field_and_range() -> None:
    fw, _, _ = make()
    axis = fw.axis(2)
    with pytest.raises(LimitError) as err:
        axis.set_amplitude(250.0)
    assert (err.value.field, err.value.lo, err.value.hi) == ("voltage", 0.0, 200.0)
    assert "e+" not in str(err.value)
    with pytest.raises(LimitError):
        axis.set_frequency(math.nan)
    with pytest.raises(LimitError):
        axis.set_flyback("linear", 0.02)  # longer than the 10 ms period
    with pytest.raises(FirmwareError, match="wrong mode"):
        axis.step(3)  # still grounded
    with pytest.raises(FirmwareError):
        fw.axis(4)  # empty slot
    with pytest.raises(FirmwareError):
        fw.axis(8)  # no such slot


def test_fault_grounds_and_blocks_stepping_until_cleared() -> None:
    fw, rec, clock = make()
    axis = fw.axis(1)
    axis.set_amplitude(200.0)
    axis.set_mode("stp")
    axis.run_continuous(up=True)
    fw.run(clock, max_ticks=25)
    axis.inject_fault(Fault.OVERTEMP)
    status = axis.status()
    assert status.mode == "gnd" and not status.moving and status.faults == ("overtemp",)
    with pytest.raises(FirmwareError, match="fault"):
        axis.set_mode("stp")
    fw.run(clock, max_ticks=30)
    assert rec.volts()[-1] == 0.0
    axis.clear_faults()
    axis.set_mode("stp")
    assert axis.status().fault_word == 0


class LateClock(VirtualClock):
    """Virtual time, but one chosen tick wakes ``late_s`` after its deadline."""

    realtime = True

    def __init__(self, late_tick: int, late_s: float) -> None:
        super().__init__()
        self.late_tick, self.late_s, self.calls = late_tick, late_s, 0

    def sleep_until(self, deadline_s: float) -> float:
        self.calls += 1
        extra = self.late_s if self.calls == self.late_tick else 0.0
        return super().sleep_until(deadline_s + extra)


def test_late_tick_within_buffer_is_no_underrun_and_longer_one_holds_the_dac() -> None:
    fw, rec, _ = make(dac_buffer_s=0.010, watchdog_s=1.0)
    fw.run(LateClock(5, 0.008), max_ticks=20)
    summary = fw.tick_summary()
    assert summary["underruns"] == 0 and summary["late_ticks"] == 1
    assert summary["missed_deadlines"] == 8

    fw, rec, _ = make(dac_buffer_s=0.010, watchdog_s=1.0)
    axis = fw.axis(1)
    axis.set_amplitude(100.0)
    axis.set_frequency(50.0)
    axis.set_mode("stp")
    axis.run_continuous(up=True)
    fw.run(LateClock(5, 0.030), max_ticks=20)
    summary = fw.tick_summary()
    assert summary["underruns"] == 1
    # the last fill (tick at 3 ms) reached 13 ms; the 4 ms tick woke at 34 ms: the DAC
    # held its last sample for 21 ms
    gap = summary["underrun_samples"]
    assert gap == 2100
    v = rec.volts()
    held = v[1300 : 1300 + gap]
    assert np.all(held == held[0])
    assert axis.status().fault_word == 0


class WorldWorkClock(VirtualClock):
    """Virtual time that runs on while the world's sinks compute (``spend``: CPU time) or wait
    for the CPU (``wait``), as wall time does."""

    realtime = True

    def __init__(self) -> None:
        super().__init__()
        self._work = 0.0

    def spend(self, seconds: float) -> None:
        self._now += seconds
        self._work += seconds

    def wait(self, seconds: float) -> None:
        self._now += seconds

    def work_s(self) -> float:
        return self._work


def stepping_on_world_work_clock() -> tuple[Firmware, WorldWorkClock, Axis]:
    """Axis 1 stepping on at 1 kHz, the firmware to run on a :class:`WorldWorkClock`."""
    fw = Firmware(FirmwareConfig(watchdog_s=1.0))
    axis = fw.axis(1)
    axis.set_frequency(1000.0)
    axis.set_amplitude(50.0)
    axis.set_mode("stp")
    axis.run_continuous(up=True)
    return fw, WorldWorkClock(), axis


def test_a_slow_world_makes_the_device_wait_and_nothing_it_reports_runs_ahead_of_the_world() -> None:
    """The world's physics takes 5 ms of CPU time per 1 ms tick (a planar plant slipping two
    parts on a loaded machine): the device's time stands still for it, so ticks stay on time,
    each hands the world one tick of samples, and the step counter the host reads while the world computes
    counts only samples the world has had, or half a tick more.  (Until 2026-11-28 the DAC
    played on by the wall clock: the host read a burst done ~1 s before the camera showed it.)"""
    fw, clock, axis = stepping_on_world_work_clock()
    blocks: list[int] = []
    ahead: list[int] = []

    def slow_world(number: int, first: int, volts: np.ndarray) -> None:
        if number != 1:
            return
        blocks.append(volts.size)
        clock.spend(5e-3)
        ahead.append(fw.command_sample() - (first + volts.size))

    fw.add_sink(slow_world)
    fw.run(clock, max_ticks=200)
    summary = fw.tick_summary()
    assert summary["late_ticks"] == 0 and summary["missed_deadlines"] == 0 and summary["underruns"] == 0
    assert set(blocks[1:]) == {fw.config.samples_per_tick}
    assert max(ahead) <= fw.config.samples_per_tick // 2
    # the device ran 200 ticks of its time, 1 ms of steps each; the clock 5.5 ms each: the
    # world's 5 ms, of which the device waited 4.5, and the tick's other 0.5 ms
    assert axis.status().step_counter == pytest.approx(200, abs=2)
    assert clock.now_s() == pytest.approx(200 * 5.5e-3, rel=0.01)
    assert summary["world_wait_s"] == pytest.approx(199 * 4.5e-3, rel=0.01)


def test_time_the_tick_thread_waits_for_the_cpu_is_played_through() -> None:
    """A world that waits 5 ms for the CPU each tick but computes nothing: the DAC plays on by
    the clock, as a real one would while its firmware is late (missed deadlines, one tick's
    worth of samples and more per tick), and the device's time is the clock's."""
    fw, clock, axis = stepping_on_world_work_clock()
    fw.add_sink(lambda number, first, volts: clock.wait(5e-3) if number == 1 else None)
    fw.run(clock, max_ticks=40)
    assert fw.tick_summary()["missed_deadlines"] >= 150 and fw.tick_summary()["world_wait_s"] == 0
    assert axis.status().step_counter == pytest.approx(1e3 * clock.now_s(), abs=2)


def test_watchdog_grounds_every_axis() -> None:
    fw, _, _ = make(watchdog_s=0.05)
    axis = fw.axis(1)
    axis.set_amplitude(10.0)
    axis.set_mode("stp")
    axis.run_continuous(up=False)
    fw.run(LateClock(3, 0.2), max_ticks=5)
    for n in fw.axis_numbers:
        status = fw.axis(n).status()
        assert status.mode == "gnd" and status.faults == ("watchdog",)


def test_host_watchdog_stops_continuous_motion_without_host_commands() -> None:
    fw, _, clock = make(host_watchdog_s=0.05)
    axis = fw.axis(1)
    axis.set_amplitude(10.0)
    axis.set_mode("stp")
    axis.run_continuous(up=True)
    for _ in range(4):
        fw.run(clock, max_ticks=20)
        fw.host_activity()
    assert axis.status().moving
    fw.run(clock, max_ticks=60)
    assert axis.status().faults == ("host_watchdog",)


def test_virtual_time_is_deterministic() -> None:
    streams = []
    for _ in range(2):
        fw, rec, clock = make()
        axis = fw.axis(1)
        axis.set_amplitude(80.0)
        axis.set_flyback("half-cosine", 0.0004)
        axis.set_mode("stp")
        axis.step(-5)
        fw.run(clock, max_ticks=80)
        streams.append(rec.volts())
    np.testing.assert_array_equal(streams[0], streams[1])


def test_stop_freezes_the_output_mid_ramp() -> None:
    fw, rec, clock = make(dac_buffer_s=0.001)
    axis = fw.axis(1)
    axis.set_frequency(10.0)
    axis.set_amplitude(100.0)
    axis.set_mode("stp")
    axis.run_continuous(up=True)
    fw.run(clock, max_ticks=30)
    axis.stop()
    fw.run(clock, max_ticks=10)
    v = rec.volts()
    assert 20.0 < v[-1] < 40.0  # about 30 % up the 100 ms ramp
    assert np.all(v[-500:] == v[-1])
    assert axis.status().step_counter == 0


def test_ground_acts_from_the_next_played_sample_not_after_the_buffer() -> None:
    fw, rec, clock = make(dac_buffer_s=0.020)
    axis = fw.axis(1)
    axis.set_amplitude(200.0)
    axis.set_frequency(20.0)
    axis.set_mode("stp")
    axis.run_continuous(up=True)
    fw.run(clock, max_ticks=31)
    before = rec.volts()
    axis.ground()
    fw.run(clock, max_ticks=1)
    after = rec.volts()[before.size :]
    step = fw.max_codes_per_sample * fw.lsb_v
    # 60 % up a 200 V ramp: it falls at the current limit from the very first sample to 0 V
    assert before[-1] > 100.0
    ramp = int(before[-1] // step)
    np.testing.assert_allclose(np.diff(np.concatenate(([before[-1]], after[:ramp]))), -step, rtol=1e-9)
    assert np.all(after[ramp + 1 :] == 0.0)
    assert axis.status().step_counter == 0


@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(0, 65535), min_size=1, max_size=80), st.integers(0, 65535), st.integers(1, 5000))
def test_slew_limiter_matches_the_sample_by_sample_definition(
    target: list[int], start: int, max_step: int
) -> None:
    expected, code = [], start
    for want in target:
        code += max(-max_step, min(max_step, want - code))
        expected.append(code)
    got = _slew_limit(np.array(target, dtype=np.int64), start, max_step)
    assert got.tolist() == expected


def test_settings_changed_mid_burst_keep_its_step_count_and_stop_ends_it() -> None:
    fw, _, clock = make()
    axis = fw.axis(1)
    axis.set_amplitude(50.0)
    axis.set_mode("stp")
    axis.step(20)  # 200 ms at 100 Hz
    fw.run(clock, max_ticks=55)
    axis.set_amplitude(80.0)
    axis.set_frequency(200.0)  # the rest of the burst runs twice as fast
    fw.run(clock, max_ticks=120)
    status = axis.status()
    assert status.step_counter == 20 and not status.moving
    axis.step(-30)
    fw.run(clock, max_ticks=40)
    axis.stop()
    stopped_at = axis.status().step_counter
    fw.run(clock, max_ticks=100)
    assert axis.status().step_counter == stopped_at
    assert 20 - 9 <= stopped_at <= 20 - 7  # 40 ms at 200 Hz = 8 periods


class HandClock(VirtualClock):
    """Virtual time that the test moves between ticks, as wall time passes between them."""

    realtime = True

    def advance_to(self, t_s: float) -> None:
        self._now = t_s


def test_commands_between_ticks_act_when_they_arrive_not_at_the_last_tick() -> None:
    """A real DAC plays on between the firmware's ticks: ``seta`` 0.3 ms and 0.6 ms after a
    tick change the offset 30 and 60 samples (100 kS/s) after it, as two increments.  Acting
    from the last tick's sample would merge them into one jump of twice the size."""
    fw, rec, _ = make(dac_buffer_s=0.010)
    clock = HandClock()
    axis = fw.axis(1)
    axis.set_mode("off")
    fw.run(clock, max_ticks=3)  # ticks at 0, 1 and 2 ms: 200 samples at 0 V
    clock.advance_to(0.0023)
    axis.set_offset(0.5)
    clock.advance_to(0.0026)
    axis.set_offset(1.0)
    fw.run(clock, max_ticks=2)  # ticks at 3 and 4 ms
    v = rec.volts()
    assert v.size == 400
    lsb = fw.lsb_v
    assert np.all(v[:230] == 0.0)
    assert np.all(np.abs(v[231:260] - 0.5) <= lsb)  # 0.5 V reached within a sample (slope limit)
    assert np.all(np.abs(v[261:] - 1.0) <= lsb)


def ready_at_1khz(clock: HandClock) -> tuple[Firmware, Recorder, Axis]:
    """Axis 1 set to step at 1 kHz, 50 V; one tick at 0 s run on ``clock`` (the DAC starts)."""
    fw, rec, _ = make(dac_buffer_s=0.010)
    axis = fw.axis(1)
    axis.set_frequency(1000.0)
    axis.set_amplitude(50.0)
    axis.set_mode("stp")
    fw.run(clock, max_ticks=1)
    return fw, rec, axis


def three_steps_at_1khz(clock: HandClock) -> tuple[Firmware, Axis]:
    """Axis 1 stepping 3 times at 1 kHz from 0 s; ``clock`` stands at the tick at 2 ms (200
    samples played, 2 steps counted), the burst ends at 3 ms."""
    fw, _, axis = ready_at_1khz(clock)
    axis.step(3)
    fw.run(clock, max_ticks=2)  # ticks at 1 and 2 ms
    return fw, axis


def test_status_between_ticks_is_what_the_dac_has_played_by_then() -> None:
    """A burst of 3 steps at 1 kHz ends at 3 ms.  Asked at 3.05 ms, before the tick at 4 ms has
    counted the samples since 2 ms, the axis is idle with its 3 steps (not moving with 2)."""
    clock = HandClock()
    _, axis = three_steps_at_1khz(clock)
    assert axis.status().moving and axis.status().step_counter == 2
    clock.advance_to(0.00305)
    status = axis.status()
    assert not status.moving and status.step_counter == 3
    assert axis.wait_idle(0.0)


class CreepingClock(HandClock):
    """Virtual time that moves on by ``creep_s`` at every reading, as wall time does."""

    creep_s = 0.0

    def now_s(self) -> float:
        self._now += self.creep_s
        return self._now


def test_status_is_one_instant_even_when_the_dac_plays_on_while_it_is_taken() -> None:
    """The count and ``moving`` come from one reading of the DAC's sample: asked one sample
    before a burst's last step, with a sample passing between two readings of the clock, the
    status is (2 steps, moving) or (3, idle), never (2, idle): the executor would then take
    a 2-step count as final."""
    clock = CreepingClock()
    fw, axis = three_steps_at_1khz(clock)
    clock.advance_to(0.003 - 1.5 / fw.sample_rate)  # the sample before the last step's
    clock.creep_s = 1.0 / fw.sample_rate
    status = axis.status()
    assert (status.step_counter, status.moving) in ((2, True), (3, False))


def test_a_burst_starts_at_its_commands_arrival_however_long_the_firmware_works_on_it() -> None:
    """``stepu`` regenerates the DAC buffer twice (to stop what plays, then for the burst): ~3 ms
    each here.  The burst starts at the sample the DAC played when the command arrived, not
    after the first regeneration (it did until 2026-11-28: a burst cut by ``stop`` then played
    fewer steps than the time between the two commands, and the ANC300 driver's estimate,
    right about the commands, counted more steps than the plant had made)."""
    clock = CreepingClock()
    fw, rec, axis = ready_at_1khz(clock)
    clock.advance_to(0.0003)
    clock.creep_s = 0.002  # each reading of the clock: 2 ms of the firmware's work
    axis.step(3)
    clock.creep_s = 0.0
    arrived = round(0.0023 * fw.sample_rate)  # the first reading: the command's arrival
    fw.run(clock, max_ticks=9)
    v = rec.volts()
    first_move = int(np.flatnonzero(v != v[0])[0])
    assert first_move == pytest.approx(arrived, abs=2)
