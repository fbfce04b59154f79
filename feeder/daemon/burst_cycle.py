"""A move's burst cycle: play a burst, follow it to its end, measure the part after it.

No I/O: :class:`BurstCycle` keeps, for :class:`~feeder.daemon.policy.Policy`, the
burst in flight and the one played but not yet measured, the readings since the
output last changed and the sensor's latency as seen.  After a burst (or a change
of the output) the part is measured once ``settle_s`` (stack ringing, sensor
latency) or, if longer, the sensor's latency as seen
(:class:`~feeder.daemon.sensor_latency.SensorLatency`) has passed,
the last :func:`agreeing` fresh readings agree (the part settled in them; the last
``average_samples`` of them are averaged) and, for a burst
the navigator expects to move a part visibly, a reading showed that it moved: frames
that lag behind the latency seen still show the part moving or not yet moved.  Up to
:data:`~feeder.daemon.sensor_latency.MAX_SETTLE_S` more for that, then the part is
measured without learning from frames that never agreed.  A stopped burst counts the
steps its drive's step counter says it played (:func:`counter_difference`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from feeder.daemon.jobs import Burst, Command, Job, LoopSettings, Reading, StepMode
from feeder.daemon.line_navigator import mean_reading
from feeder.daemon.navigator import Navigator, part_pose
from feeder.daemon.sensor_latency import MAX_SETTLE_S, SensorLatency
from feeder.daemon.step_estimator import FORWARD

MIN_AGREEING = 2
"""Fresh readings that must agree before the part is measured, however few are averaged: one
reading cannot tell a part at rest from one still moving, and a frame exposed in a burst's tail
can arrive after the settle time (a loaded machine delays the camera's frames beyond the
latency seen so far): measured, it sent the next burst from where the part was passing."""


def agreeing(settings: LoopSettings) -> int:
    """How many of the latest fresh readings must agree before the part is measured."""
    return max(MIN_AGREEING, settings.average_samples)


def counter_difference(after: int, before: int) -> int:
    """Steps between two readings of a drive's step counter, which wraps as an I32 (CANopen's
    0x2012: 2³¹ − 1 + 1 step is −2³¹); exact while fewer than 2³¹ steps lie between them."""
    return (after - before + (1 << 31)) % (1 << 32) - (1 << 31)


@dataclass
class _Burst:
    """The burst in flight."""

    burst: Burst
    before: Reading
    learnable: bool
    reversed: bool
    counter_before: int | None = None
    end_s: float = math.inf  # acknowledged + steps/f
    started_s: float = math.inf  # acknowledged
    ended_s: float = math.inf  # its end confirmed
    moved_seen: bool = False  # a reading after the start showed the part moved
    visible: bool = False  # expected to move a part beyond the settle band (the navigator's)
    confirming: bool = False


class BurstCycle:
    """The bursts of the running move and the readings that measure them.  See the module
    docstring.

    modes: every axis' waveform modes (a burst lasts its steps at its mode's frequency).
    """

    def __init__(
        self, modes: dict[str, dict[str, StepMode]], settings: LoopSettings, navigator: Navigator
    ) -> None:
        self.modes = modes
        self.settings = settings
        self.navigator = navigator
        self.flying: _Burst | None = None  # started, its end not yet confirmed
        self.measured: _Burst | None = None  # over, the part not yet measured after it
        self.samples: list[Reading] = []  # readings since settle_until
        self.settle_until = 0.0
        self._latency = SensorLatency()
        self._last_direction: dict[str, str] = {}  # axis → direction of its last burst

    @property
    def latency_s(self) -> float:
        """The sensor's latency as seen (s)."""
        return self._latency.latency_s

    def _settle_s(self) -> float:
        return self._latency.settle_s(self.settings.settle_s)

    def watch(self, now: float, settle: bool = True) -> None:
        """The output changed at ``now``: collect readings from ``settle_s`` on (at once if not
        ``settle``)."""
        self.settle_until = now + (self._settle_s() if settle else 0.0)
        self.samples = []

    def on_sample(self, reading: Reading, arrival_s: float, state: str) -> None:
        """A reading that arrived at ``arrival_s`` while the policy was in ``state``."""
        if state in ("settling", "holding") and arrival_s >= self.settle_until:
            self.samples.append(reading)
        for burst in (self.flying, self.measured):  # in flight, or over and not yet measured
            if burst is None or burst.moved_seen or arrival_s < burst.started_s:
                continue
            if not self.navigator.settled([burst.before, reading]):
                burst.moved_seen = True
                self._latency.seen(arrival_s - burst.started_s)
                if burst is self.measured and state == "settling":  # now it is known
                    self.settle_until = burst.ended_s + self._settle_s()

    def start(
        self, job: Job, nxt: Burst, reading: Reading, unmeasured_switch: bool, grounded: bool = False
    ) -> Command | tuple[str, str]:
        """Count ``nxt``, decided from ``reading``, into ``job`` and follow it: the command that
        plays it, or (status, reason) when it reverses once too often.  ``grounded``: decided
        from a grounded pose (a done pose checked), so a reversal is the ground's, not one to
        count; nor is a leg of a planned path's (``nxt.path``: ``max_bursts`` bounds those)."""
        previous = job.last_directions.get(nxt.axis)  # a reversal is per axis: x+ then y− is none
        if previous is not None and nxt.direction != previous and not (grounded or nxt.path):
            job.reversals += 1
            if job.reversals > self.settings.max_reversals * len(self.navigator.axes):
                return ("oscillating", f"{job.reversals} direction reversals without reaching the tolerance")
        reversed_ = self._last_direction.get(nxt.axis) != nxt.direction  # None: unknown history
        self._last_direction[nxt.axis] = nxt.direction
        self.flying = _Burst(nxt, reading, learnable=not (reversed_ or unmeasured_switch), reversed=reversed_,
                             visible=self.navigator.expects_motion(nxt, reading))  # fmt: skip
        job.steps += nxt.steps
        job.bursts += 1
        job.bursts_per_axis[nxt.axis] = job.bursts_per_axis.get(nxt.axis, 0) + 1
        job.last_directions[nxt.axis] = nxt.direction
        signed = nxt.steps if nxt.direction == FORWARD else -nxt.steps
        return Command("step", steps=signed, axis=nxt.axis)

    def acknowledged(self, at_s: float, counter: int | None) -> None:
        """The burst in flight started at ``at_s``, its drive's step counter at ``counter``."""
        burst = self.flying
        assert burst is not None
        burst.counter_before = counter
        b = burst.burst
        burst.end_s = at_s + b.steps / self.modes[b.axis][b.mode].settings.frequency_hz
        burst.started_s = at_s

    def confirmation(self, now: float) -> Command | None:
        """The command that confirms the end of the burst in flight, once it should be over by
        ``now``; None."""
        burst = self.flying
        assert burst is not None
        if now < burst.end_s or burst.confirming:
            return None
        burst.confirming = True
        return Command("confirm_end", timeout_s=self.settings.burst_grace_s, axis=burst.burst.axis)

    def ended(self, at_s: float) -> None:
        """The burst in flight is confirmed over at ``at_s``: measure the part after it."""
        burst = self.flying
        assert burst is not None
        self.flying = None
        self.measured = burst
        burst.ended_s = at_s
        self.watch(at_s)
        if not self._latency.known and not burst.moved_seen:  # the sensor's latency is unknown:
            self.settle_until = at_s + MAX_SETTLE_S  # wait to see the burst's motion

    def stop_command(self) -> Command:
        """The command that stops the output: on the burst in flight's axis (x when none)."""
        return Command("stop", axis=self.flying.burst.axis if self.flying is not None else "x")

    def unplayed(self, counter: int | None) -> int:
        """The burst in flight was stopped, its drive's step counter then at ``counter``: how many
        of its steps it did not play."""
        burst = self.flying
        assert burst is not None
        played = burst.burst.steps
        if counter is not None and burst.counter_before is not None:
            played = min(played, abs(counter_difference(counter, burst.counter_before)))
        self.flying = None
        return burst.burst.steps - played

    def measure(self, job: Job, now: float) -> Reading | None:
        """The parts' reading once they may be measured, having learned from the burst before it
        (``job``'s start when it is the first); None: wait."""
        s = self.settings
        need = agreeing(s)
        if now < self.settle_until or len(self.samples) < need:
            return None
        b = self.measured
        if b is not None and b.visible and not b.moved_seen and now < b.ended_s + MAX_SETTLE_S:
            return None  # the frames do not show the burst's motion yet (they lag more than seen): wait
        steady = self.navigator.settled(self.samples[-need:])
        if not steady and now < self.settle_until + MAX_SETTLE_S:
            return None  # the frames still show the part moving (they lag behind the motion): wait
        reading = mean_reading(self.samples[-s.average_samples :])
        self.samples = []
        if job.start_m is None:
            job.start_pose = part_pose(job, reading)
            job.start_m = job.start_pose[0]
        if b is not None:
            if self.navigator.learn(b.burst, b.learnable and steady, b.before, reading):
                job.stalls += 1
            else:
                job.stalls = 0
            self.measured = None
        return reading

    def verdict(self, job: Job, reading: Reading) -> Burst | tuple[str, str] | None:
        """What follows the measurement ``reading``: (status, reason) when ``job`` is over, a
        calibration's next burst, or None: the navigator decides."""
        outside = self.navigator.outside(reading)
        if outside is not None:
            return ("limit", outside)
        if job.stalls >= self.settings.stall_bursts:
            return ("stalled", f"{job.stalls} bursts in a row barely moved the part")
        if job.target_m is None and job.target_pose is None:
            if not job.planned:
                return ("done", "calibration complete")
            return job.planned.popleft()
        limit = self.settings.max_bursts * len(self.navigator.axes)
        if job.bursts >= limit:
            return ("unreachable", f"no convergence after {job.bursts} bursts")
        return None

    def settled(self) -> Reading | None:
        """The average of the last ``average_samples`` readings when the last :func:`agreeing`
        agree; None."""
        need = agreeing(self.settings)
        recent = self.samples[-need:]
        if len(recent) == need and self.navigator.settled(recent):
            return mean_reading(recent[-self.settings.average_samples :])
        return None

    def clear(self) -> None:
        """The move is over: no burst to follow or measure."""
        self.flying = None
        self.measured = None
