"""The closed loop's decisions as an explicit state machine: measurements in, commands out.

No I/O, no threads, no sleeps: :class:`Policy` is fed sensor samples, the
executor's completions and the time, and answers with :class:`Command`s for
the amplifier and :class:`Event`s for the record.  :mod:`feeder.daemon.control_loop`
runs it on a fixed-rate tick and does the I/O; the unit tests drive it with a
fake clock.

States (:data:`STATES`):

- ``idle``: no job.
- ``moving``: a job is preparing the output or a burst is playing.
- ``settling``: the burst is over; wait ``settle_s`` (stack ringing, sensor
  latency), average ``average_samples`` fresh samples, learn, decide.
- ``holding``: the job is over early (stop, sensor or limit): the output was
  stopped and the part is watched until the sensor reads it settled (the
  last ``average_samples`` readings agree within the tolerance); only then is
  the result, with the settled position and the steps actually played, final.
- ``fault``: the amplifier link or the sensor is lost; no job is accepted
  until the link is restored (:meth:`Policy.link_restored`, :meth:`Policy.sensor_restored`).

A move alternates *measure* and *burst*.  Far from the target the *coarse*
waveform aims one coarse step short (never past the target); the last stretch
uses the *fine* waveform, whose step is at most twice the tolerance, so the
final error is at most half a fine step plus scatter: no overshoot, no hunting.
A part within tolerance but more than half a fine step away gets one more fine
step (once per move).  The estimators learn from every burst but the first
after a direction reversal (or the first of all): that one loses part of a
step to the plate's state left by the other direction.  Leaving ground or
changing the waveform moves the plate's rest position, so the loop measures
again after it (once per burst).

A move ends on request (``stopped``), on stall, on travel limits, on too many
reversals, on a lost sensor or link (``fault``), or when the target is within
tolerance (``done``).
"""

from __future__ import annotations

import collections
import math
import threading  # a Job's done event only: the policy never waits on it
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from feeder.daemon.step_estimator import BACKWARD, DIRECTIONS, FORWARD, StepEstimate, StepEstimator
from feeder.drivers.amplifier import DriveSettings

COARSE = "coarse"
FINE = "fine"
STATES = ("idle", "moving", "settling", "holding", "fault")


@dataclass(frozen=True)
class StepMode:
    """A waveform the loop steps with and the planner's predicted step for it (m)."""

    name: str
    settings: DriveSettings
    predicted_step_m: float
    predicted_band_m: tuple[float, float]

    @property
    def seed(self) -> StepEstimate:
        """Estimator seed: prediction ± half-width of the band (at least 5 %)."""
        half = 0.5 * (self.predicted_band_m[1] - self.predicted_band_m[0])
        return StepEstimate.seed(self.predicted_step_m, max(half, 0.05 * self.predicted_step_m))


@dataclass(frozen=True)
class LoopSettings:
    """Tuning of the loop; lengths in m, times in s."""

    rate_hz: float = 100.0
    tolerance_m: float = 1e-6
    min_position_m: float = -10e-3
    max_position_m: float = 10e-3
    settle_s: float = 0.05
    average_samples: int = 3
    max_burst_steps: int = 400
    stall_fraction: float = 0.3
    stall_bursts: int = 2
    max_reversals: int = 4
    max_bursts: int = 60
    burst_grace_s: float = 1.0
    sensor_noise_m: float = 0.1e-6
    step_scatter_fraction: float = 0.05
    forgetting: float = 0.98
    position_save_s: float = 0.25
    hold_timeout_s: float = 3.0


@dataclass(frozen=True)
class Burst:
    """One burst of a job: ``steps`` > 0 in ``direction`` with waveform ``mode``."""

    mode: str
    direction: str
    steps: int


# -- commands to the executor, and what it reports back --------------------------------


@dataclass(frozen=True)
class Command:
    """An amplifier action for the executor (``kind``: see :data:`COMMANDS`)."""

    kind: str
    mode: str = ""
    steps: int = 0
    timeout_s: float = 0.0


COMMANDS = ("enable", "apply", "step", "confirm_end", "stop")
"""enable: leave ground (clearing a latched transient fault); apply: load a mode's waveform;
step: start a burst of ``steps`` (signed); confirm_end: check the burst is over (``stepw``);
stop: stop the output now."""


@dataclass(frozen=True)
class Completion:
    """The executor's report on a command.

    at_s: loop time when the command was acknowledged; counter: the drive's
    step count (``steps_played``) *before* a ``step``, *after* a ``stop``;
    error: None on success; link_lost: the error was a lost link.
    """

    command: Command
    at_s: float
    error: str | None = None
    link_lost: bool = False
    counter: int | None = None
    estimated: bool = False


# -- what the record needs --------------------------------------------------------------


@dataclass
class JobResult:
    """How a move (or calibration) ended.

    status: ``done``, ``stopped``, ``stalled``, ``limit``, ``oscillating``,
    ``unreachable``, ``fault``.  Positions in m; ``trace`` is (loop time s, m).
    steps_estimated: the steps of a burst cut short were estimated from time
    (a drive that counts none, e.g. the ANC300).
    """

    kind: str
    status: str
    reason: str
    target_m: float | None
    start_m: float | None
    reached_m: float | None
    steps: int
    bursts: int
    duration_s: float
    estimates: dict[str, dict[str, float]]
    trace: list[tuple[float, float]] = field(default_factory=list)
    steps_estimated: bool = False

    @property
    def error_m(self) -> float | None:
        if self.target_m is None or self.reached_m is None:
            return None
        return self.reached_m - self.target_m

    def as_dict(self, with_trace: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {
            "kind": self.kind,
            "status": self.status,
            "reason": self.reason,
            "target_m": self.target_m,
            "start_m": self.start_m,
            "reached_m": self.reached_m,
            "error_m": self.error_m,
            "steps": self.steps,
            "bursts": self.bursts,
            "steps_estimated": self.steps_estimated,
            "duration_s": self.duration_s,
            "estimates": self.estimates,
        }
        if with_trace:
            out["trace"] = [[t, x] for t, x in self.trace]
        return out


class Job:
    """A move to ``target_m`` (or by ``by_m`` from where the part is when it starts), or a
    calibration sequence of fixed bursts.  ``on_start`` runs when the loop accepts it (the
    record is written before the first step: the loop sets ``recorded``); ``on_done`` with
    the result at the end, then ``done`` is set.  The policy only reads and writes the
    progress fields; the callbacks and ``done`` belong to the loop."""

    def __init__(
        self,
        kind: str,
        target_m: float | None = None,
        bursts: tuple[Burst, ...] = (),
        *,
        by_m: float | None = None,
        on_start: Callable[[], None] | None = None,
        on_done: Callable[[JobResult], None] | None = None,
    ) -> None:
        self.kind = kind
        self.target_m = target_m
        self.by_m = by_m
        self.planned = collections.deque(bursts)
        self.on_start = on_start
        self.on_done = on_done
        self.record_id: int | None = None
        self.recorded = False
        self.done = threading.Event()
        self.result: JobResult | None = None
        # progress
        self.started_s = 0.0
        self.start_m: float | None = None
        self.steps = 0
        self.bursts = 0
        self.stalls = 0
        self.reversals = 0
        self.refined = False
        self.switched = False
        self.last_direction: str | None = None
        self.trace: list[tuple[float, float]] = []
        self.steps_estimated = False


@dataclass(frozen=True)
class Started:
    """Event: write the job's record (``job.on_start``), then mark it recorded."""

    job: Job


@dataclass(frozen=True)
class Finished:
    """Event: the job is over; record the result and release the caller."""

    job: Job
    result: JobResult


@dataclass(frozen=True)
class SavePosition:
    """Event: persist the part's position (m)."""

    position_m: float


@dataclass(frozen=True)
class Fault:
    """Event: a link is lost (``link``: ``amplifier`` or ``sensor``)."""

    link: str
    message: str


Output = Command | Started | Finished | SavePosition | Fault


@dataclass
class _Burst:
    """The burst in flight."""

    burst: Burst
    from_m: float
    learnable: bool
    reversed: bool
    counter_before: int | None = None
    end_s: float = math.inf  # acknowledged + steps/f
    confirming: bool = False


class Policy:
    """The loop's state machine over one axis.  See the module docstring."""

    def __init__(
        self,
        modes: dict[str, StepMode],
        settings: LoopSettings,
        estimates: dict[str, StepEstimate] | None = None,
    ) -> None:
        if set(modes) != {COARSE, FINE}:
            raise ValueError("modes must be exactly 'coarse' and 'fine'")
        self.modes = modes
        self.settings = settings
        self.estimators: dict[str, StepEstimator] = {}
        restored = estimates or {}
        for name, mode in modes.items():
            for direction in DIRECTIONS:
                key = f"{name}/{direction}"
                self.estimators[key] = StepEstimator(
                    restored.get(key, mode.seed),
                    sensor_noise_m=settings.sensor_noise_m,
                    step_scatter_m=settings.step_scatter_fraction * mode.predicted_step_m,
                    forgetting=settings.forgetting,
                )
        self.state = "idle"
        self.job: Job | None = None
        self.position_m: float | None = None
        self.fault: str | None = None
        self.sensor_lost: str | None = None
        self.store_unwritable: str | None = None  # set by the loop while records cannot be written
        self.last_result: JobResult | None = None
        self._stop_reason: str | None = None
        self._pending: Command | None = None  # sent, not yet completed
        self._burst: _Burst | None = None
        self._applied: str | None = None
        self._enabled = False
        self._last_direction: str | None = None
        self._settle_until = 0.0
        self._samples: list[float] = []
        self._measured: _Burst | None = None
        self._finish_as: tuple[str, str] | None = None  # (status, reason) once held
        self._hold_until = 0.0
        self._position_saved_s = -math.inf
        self._now = 0.0
        self._out: list[Output] = []

    # -- inputs ----------------------------------------------------------------------

    def submit(self, job: Job, now: float) -> str | None:
        """Accept ``job``; the reason it is refused, or None."""
        if self.fault is not None:
            return f"in fault state: {self.fault}"
        if self.sensor_lost is not None:
            return f"sensor lost: {self.sensor_lost}"
        if self.store_unwritable is not None:
            return self.store_unwritable
        if self.job is not None:
            return f"a {self.job.kind} is in progress"
        if job.by_m is not None:
            if self.position_m is None:
                return "position uncertain: no sensor reading yet for a relative move"
            job.target_m = self.position_m + job.by_m
        if job.target_m is not None:
            s = self.settings
            if not (s.min_position_m <= job.target_m <= s.max_position_m):
                return (
                    f"target {job.target_m:.6g} m is outside the travel limits "
                    f"[{s.min_position_m:.6g}, {s.max_position_m:.6g}] m"
                )
        job.started_s = self._now = now
        self.job = job
        self._stop_reason = None
        self._finish_as = None
        self._enter_settling(now, settle=False)
        if not self._enabled:
            self.state = "moving"
        self._out.append(Started(job))
        return None

    def request_stop(self, reason: str = "stop requested") -> bool:
        """Ask the active job to stop; False when there is none."""
        if self.job is None or self._finish_as is not None:
            return self.job is not None
        self._stop_reason = reason
        return True

    def on_sample(self, position_m: float, arrival_s: float) -> None:
        """A sensor reading (m) that arrived at loop time ``arrival_s``."""
        self.position_m = position_m
        job = self.job
        if job is None:
            return
        job.trace.append((arrival_s, position_m))
        if self.state in ("settling", "holding") and arrival_s >= self._settle_until:
            self._samples.append(position_m)

    def on_sensor_lost(self, message: str) -> None:
        if self.sensor_lost is not None:
            return
        self.sensor_lost = message
        self.position_m = None
        self._out.append(Fault("sensor", message))
        if self.job is not None:
            self._emit_stop()
            self._finish(self.job, "fault", f"sensor lost: {message}", None)
        self.state = "fault"

    def on_completion(self, done: Completion) -> None:
        """The executor finished ``done.command``."""
        if done.command == self._pending:
            self._pending = None
        self._now = max(self._now, done.at_s)
        kind = done.command.kind
        if done.error is not None:
            if done.link_lost:
                self._link_lost(done.error)
            elif kind != "stop":
                self._enabled = False  # the next job checks the output's state again
                self._applied = None
                if self.job is not None:
                    self._emit_stop()
                    self._finish(self.job, "fault", f"amplifier refused: {done.error}", None)
            return
        burst = self._burst
        if kind in ("enable", "apply"):
            if kind == "enable":
                self._enabled = True
            else:
                self._applied = done.command.mode
            if burst is None and self.job is not None and self._finish_as is None:
                self._enter_settling(done.at_s)  # the plate's rest moved: measure again
        elif kind == "step" and burst is not None:
            burst.counter_before = done.counter
            f = self.modes[burst.burst.mode].settings.frequency_hz
            burst.end_s = done.at_s + burst.burst.steps / f
        elif kind == "confirm_end" and burst is not None:
            self._burst = None
            self._measured = burst
            self._enter_settling(done.at_s)
        elif kind == "stop":
            if burst is not None and self.job is not None:
                played = burst.burst.steps
                if done.counter is not None and burst.counter_before is not None:
                    played = min(played, abs(done.counter - burst.counter_before))
                self.job.steps -= burst.burst.steps - played
                self.job.steps_estimated = self.job.steps_estimated or done.estimated
                self._burst = None
            if self.job is not None and self._finish_as is not None:
                self._enter_holding(done.at_s)

    def on_link_lost(self, message: str) -> None:
        """The amplifier link is known to be gone (e.g. the simulator behind it restarted)."""
        if self.fault is None:
            self._link_lost(message)

    def link_restored(self) -> None:
        """A new amplifier link (grounded): leave the fault state; no move resumes."""
        self.fault = None
        self._applied = None
        self._enabled = False
        self._pending = None
        if self.sensor_lost is None:
            self.state = "idle"

    def sensor_restored(self) -> None:
        """A new sensor link: the position is uncertain until it reports."""
        self.sensor_lost = None
        self.position_m = None
        if self.fault is None:
            self.state = "idle"

    # -- the tick ---------------------------------------------------------------------

    def tick(self, now: float) -> list[Output]:
        """One period: advance the active job; returns commands and events, in order."""
        self._now = now
        job = self.job
        if job is not None and self.fault is None and self.sensor_lost is None:
            self._save_position(now)
            if self._stop_reason is not None and self._finish_as is None:
                self._end_early("stopped", self._stop_reason, now)
            elif self.state == "holding":
                self._hold(job, now)
            elif self._finish_as is not None:
                pass  # the stop is on its way; hold when it is done
            elif self._pending is None:
                if self._burst is not None:
                    self._follow_burst(job, now)
                else:
                    self._measure(job, now)
        out, self._out = self._out, []
        return out

    # -- internals ---------------------------------------------------------------------

    def _send(self, command: Command) -> None:
        self._pending = command
        self._out.append(command)

    def _emit_stop(self) -> None:
        """Stop the output now if anything may be playing (jumps any command in flight)."""
        if self._burst is not None or self._pending is not None:
            self._out.append(Command("stop"))

    def _end_early(self, status: str, reason: str, now: float) -> None:
        """End the job with ``status`` once the output stopped and the part settled."""
        self._finish_as = (status, reason)
        if self._burst is not None or self._pending is not None:
            self._out.append(Command("stop"))  # holding starts when it is done
        else:
            self._enter_holding(now)

    def _link_lost(self, message: str) -> None:
        self.fault = f"amplifier link lost: {message}"
        self._pending = None
        self._out.append(Fault("amplifier", message))
        if self.job is not None:
            self._burst = None
            self._finish(self.job, "fault", self.fault, None)
        self.state = "fault"

    def _save_position(self, now: float) -> None:
        if self.position_m is not None and now - self._position_saved_s >= self.settings.position_save_s:
            self._position_saved_s = now
            self._out.append(SavePosition(self.position_m))

    def _enter_settling(self, now: float, settle: bool = True) -> None:
        self.state = "settling"
        self._settle_until = now + (self.settings.settle_s if settle else 0.0)
        self._samples = []

    def _enter_holding(self, now: float) -> None:
        self.state = "holding"
        self._settle_until = now + self.settings.settle_s
        self._hold_until = now + self.settings.hold_timeout_s
        self._samples = []

    def _hold(self, job: Job, now: float) -> None:
        """Watch the stopped part until the sensor reads it settled, then finish."""
        s = self.settings
        assert self._finish_as is not None
        status, reason = self._finish_as
        recent = self._samples[-s.average_samples :]
        settled_band = max(s.tolerance_m, 6 * s.sensor_noise_m)
        if len(recent) == s.average_samples and max(recent) - min(recent) <= settled_band:
            x = float(np.mean(recent))
            self._out.append(SavePosition(x))
            self._finish(job, status, reason, x)
        elif now >= self._hold_until:
            self._finish(
                job,
                status,
                f"{reason}; the part did not settle within {s.hold_timeout_s:g} s after the output stopped",
                self.position_m,
            )

    def _follow_burst(self, job: Job, now: float) -> None:
        burst = self._burst
        assert burst is not None
        s = self.settings
        x = self.position_m
        if x is not None and not (s.min_position_m <= x <= s.max_position_m):
            self._end_early("limit", f"part seen at {x:.6g} m, outside the travel limits; stopped", now)
            return
        if now < burst.end_s or burst.confirming:
            return
        burst.confirming = True
        self._send(Command("confirm_end", timeout_s=s.burst_grace_s))

    def _measure(self, job: Job, now: float) -> None:
        s = self.settings
        if not job.recorded:
            return  # the record comes first: a crash leaves a trace
        if not self._enabled:
            self.state = "moving"
            self._send(Command("enable"))
            return
        if now < self._settle_until or len(self._samples) < s.average_samples:
            return
        x = float(np.mean(self._samples[-s.average_samples :]))
        self._samples = []
        self._out.append(SavePosition(x))
        if job.start_m is None:
            job.start_m = x
        if self._measured is not None:
            self._learn(job, self._measured, x)
            self._measured = None
        if not (s.min_position_m <= x <= s.max_position_m):
            self._finish(job, "limit", f"part at {x:.6g} m is outside the travel limits", x)
            return
        if job.stalls >= s.stall_bursts:
            self._finish(job, "stalled", f"{job.stalls} bursts in a row barely moved the part", x)
            return
        refined = job.refined
        nxt = self._next_burst(job, x)
        if isinstance(nxt, tuple):
            self._finish(job, nxt[0], nxt[1], x)
            return
        unmeasured_switch = False
        if self._applied != nxt.mode:
            # changing the amplitude moves the plate's rest position (and the part with it):
            # apply, then measure again before the burst -- once; should the decision then
            # change waveform again, step without re-measuring (and without learning)
            unmeasured_switch = job.switched
            if job.target_m is None:
                job.planned.appendleft(nxt)
            job.refined = refined
            job.switched = True
            self.state = "moving"
            self._send(Command("apply", mode=nxt.mode))
            if not unmeasured_switch:
                return  # measure again once it is applied
            if job.target_m is None:
                job.planned.popleft()
        job.switched = False
        if job.last_direction is not None and nxt.direction != job.last_direction:
            job.reversals += 1
            if job.reversals > s.max_reversals:
                self._finish(
                    job,
                    "oscillating",
                    f"{job.reversals} direction reversals without reaching the tolerance",
                    x,
                )
                return
        reversed_ = self._last_direction != nxt.direction  # None: unknown history
        self._last_direction = nxt.direction
        self._burst = _Burst(nxt, x, learnable=not (reversed_ or unmeasured_switch), reversed=reversed_)
        job.steps += nxt.steps
        job.bursts += 1
        job.last_direction = nxt.direction
        self.state = "moving"
        # (after an unmeasured switch the apply is still in flight: the executor runs both
        # in order, and the step is what the policy waits for)
        self._send(Command("step", steps=nxt.steps if nxt.direction == FORWARD else -nxt.steps))

    def _learn(self, job: Job, burst: _Burst, x: float) -> None:
        b = burst.burst
        sign = 1.0 if b.direction == FORWARD else -1.0
        moved = sign * (x - burst.from_m)
        est = self.estimators[f"{b.mode}/{b.direction}"]
        expected = est.estimate.displacement_m(b.steps)
        if not burst.learnable:  # e.g. after a reversal: may lose up to a step
            expected -= est.estimate.step_m
        if moved < self.settings.stall_fraction * expected:
            job.stalls += 1
            return
        job.stalls = 0
        if burst.learnable:
            est.update(b.steps, moved)

    def _next_burst(self, job: Job, x: float) -> Burst | tuple[str, str]:
        """The next burst, or (status, reason) when the job is over."""
        s = self.settings
        if job.target_m is None:
            if not job.planned:
                return ("done", "calibration complete")
            return job.planned.popleft()
        if job.bursts >= s.max_bursts:
            return ("unreachable", f"no convergence after {job.bursts} bursts")
        error = job.target_m - x
        direction = FORWARD if error > 0 else BACKWARD
        distance = abs(error)
        coarse = self.estimators[f"{COARSE}/{direction}"]
        fine = self.estimators[f"{FINE}/{direction}"]
        single = fine.estimate.displacement_m(1)  # what one fine step does
        if distance <= s.tolerance_m:
            # within tolerance; one fine step more when it brings the part closer (once per
            # move, so it can never start hunting)
            if job.refined or distance <= 0.5 * single:
                return ("done", "within tolerance")
            job.refined = True
            return Burst(FINE, direction, 1)
        # aim one step short with a pessimistic (mean + 2σ) step and offset: never past the target
        c = coarse.estimate
        step_high = c.step_m + 2 * c.std_m
        offset_high = c.offset_m + 2 * c.offset_std_m
        coarse_steps = math.floor((distance - offset_high) / step_high) - 1
        if coarse_steps >= 1 and coarse.usable_step_m() > fine.usable_step_m():
            return Burst(COARSE, direction, min(coarse_steps, s.max_burst_steps))
        steps = round((distance - fine.estimate.offset_m) / fine.usable_step_m())
        if steps < 1:
            if abs(distance - single) >= distance:
                return (
                    "unreachable",
                    f"one fine step ({single:.3g} m) cannot reduce the "
                    f"error {error:.3g} m below the tolerance {s.tolerance_m:.3g} m",
                )
            steps = 1
        return Burst(FINE, direction, min(steps, s.max_burst_steps))

    def _finish(self, job: Job, status: str, reason: str, reached_m: float | None) -> None:
        now = self._now
        result = JobResult(
            kind=job.kind,
            status=status,
            reason=reason,
            target_m=job.target_m,
            start_m=job.start_m,
            reached_m=reached_m if reached_m is not None else self.position_m,
            steps=job.steps,
            bursts=job.bursts,
            duration_s=max(0.0, now - job.started_s),
            estimates=self.estimates_json(),
            trace=job.trace,
            steps_estimated=job.steps_estimated,
        )
        self.job = None
        self._burst = None
        self._pending = None
        self._measured = None
        self._finish_as = None
        self._stop_reason = None
        self.last_result = result
        if self.fault is None and self.sensor_lost is None:
            self.state = "idle"
        self._out.append(Finished(job, result))

    def estimates(self) -> dict[str, StepEstimate]:
        return {k: e.estimate for k, e in self.estimators.items()}

    def estimates_json(self) -> dict[str, dict[str, float]]:
        """Learned step and burst offset per ``mode/direction`` (m), for replies."""
        return {
            k: {
                "step_m": e.step_m,
                "std_m": e.std_m,
                "offset_m": e.offset_m,
                "offset_std_m": e.offset_std_m,
                "steps": e.steps,
            }
            for k, e in self.estimates().items()
        }
