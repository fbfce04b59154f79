"""The closed loop: a fixed-rate tick that reads the sensor and steps the part to its target.

A move alternates two phases.  *Measure*: after a burst, wait ``settle_s``
(stack ringing, sensor latency), average ``average_samples`` fresh samples,
feed the burst's displacement to the direction's :class:`StepEstimator`, then
decide.  *Burst*: command ``n`` whole steps and wait until the amplifier
reports the burst done.  Far from the target the *coarse* waveform aims one
coarse step short (never past the target); the last stretch uses the *fine*
waveform, whose step is at most twice the tolerance, so the final error is
at most half a fine step plus scatter: no overshoot, no hunting.  A part that
lands within tolerance but more than half a fine step away gets one more fine
step (once per move).

The estimators learn from every burst but the first after a direction
reversal (or the first of all, when the history is unknown): that one loses
part of a step (the plate's state left by the other direction), which is
neither the step nor the burst offset.

The loop stops a move on request, on stall (bursts that move the part by less
than ``stall_fraction`` of what the estimate predicts), on travel limits
(target outside, or the part seen outside), on too many direction reversals,
on a lost sensor and on a lost amplifier link.  Tick jitter (wake-up time −
deadline) and overruns (work that ran past the next deadline) are counted.
"""

from __future__ import annotations

import collections
import contextlib
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from feeder.daemon.step_estimator import BACKWARD, DIRECTIONS, FORWARD, StepEstimate, StepEstimator
from feeder.drivers.amplifier import Amplifier, AmplifierError, AmplifierLinkLost, DriveSettings
from feeder.drivers.sensor import PositionSample, PositionSensor, SensorLost

COARSE = "coarse"
FINE = "fine"
CLEARABLE_FAULTS = frozenset({"watchdog"})
"""Latched amplifier faults a new move may clear (transient: the firmware's tick was late)."""


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


@dataclass(frozen=True)
class Burst:
    """One burst of a job: ``steps`` > 0 in ``direction`` with waveform ``mode``."""

    mode: str
    direction: str
    steps: int


@dataclass
class JobResult:
    """How a move (or calibration) ended.

    status: ``done``, ``stopped``, ``stalled``, ``limit``, ``oscillating``,
    ``unreachable``, ``fault``.  Positions in m; ``trace`` is (loop time s, m).
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

    @property
    def error_m(self) -> float | None:
        if self.target_m is None or self.reached_m is None:
            return None
        return self.reached_m - self.target_m

    def as_dict(self, with_trace: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {
            "kind": self.kind, "status": self.status, "reason": self.reason,
            "target_m": self.target_m, "start_m": self.start_m, "reached_m": self.reached_m,
            "error_m": self.error_m, "steps": self.steps, "bursts": self.bursts,
            "duration_s": self.duration_s, "estimates": self.estimates,
        }
        if with_trace:
            out["trace"] = [[t, x] for t, x in self.trace]
        return out


class Job:
    """A move to ``target_m`` (or by ``by_m`` from where the part is when it starts), or a
    calibration sequence of fixed bursts.  ``on_start`` runs when the loop accepts it, before
    any step; ``on_done`` with the result at the end, then ``done`` is set."""

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
        self.last_direction: str | None = None
        self.trace: list[tuple[float, float]] = []
        self.burst: Burst | None = None
        self.measured_burst: Burst | None = None
        self.burst_from_m = 0.0
        self.burst_reversed = False
        self.burst_learnable = False
        self.switched = False
        self.burst_end_s = 0.0
        self.settle_until_s = 0.0
        self.samples: list[float] = []


class SensorFeed:
    """Reads the sensor in its own thread so a slow frame never stalls the tick."""

    def __init__(self, sensor: PositionSensor, timeout_s: float, clock: Callable[[], float]) -> None:
        self.sensor = sensor
        self.timeout_s = timeout_s
        self._clock = clock
        self._lock = threading.Lock()
        self._pending: list[tuple[float, PositionSample]] = []
        self.lost: str | None = None
        self._closing = False
        self._thread = threading.Thread(target=self._run, name="sensor-feed", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._closing:
            try:
                sample = self.sensor.read(self.timeout_s)
            except (SensorLost, OSError) as err:
                if not self._closing:
                    self.lost = str(err) or type(err).__name__
                return
            with self._lock:
                self._pending.append((self._clock(), sample))

    def take(self) -> list[tuple[float, PositionSample]]:
        """Samples that arrived since the last call: (arrival loop time s, sample)."""
        with self._lock:
            out, self._pending = self._pending, []
        return out

    def close(self) -> None:
        """Stop reading and close the sensor's link."""
        self._closing = True
        with contextlib.suppress(Exception):
            self.sensor.close()
        self._thread.join(timeout=self.timeout_s + 1.0)


class ControlLoop:
    """Fixed-rate closed loop over one amplifier axis and one position sensor.

    ``modes`` maps ``"coarse"``/``"fine"`` to their :class:`StepMode`;
    ``estimates`` optionally restores learned steps keyed ``"mode/direction"``.
    ``on_position`` is called with each settled position (m) and, during a job,
    with the latest reading every ``position_save_s``; ``on_fault`` with
    ``("amplifier"|"sensor", message)`` when a link is lost.
    """

    def __init__(
        self,
        amplifier: Amplifier,
        sensor: PositionSensor,
        modes: dict[str, StepMode],
        settings: LoopSettings = LoopSettings(),
        *,
        estimates: dict[str, StepEstimate] | None = None,
        on_position: Callable[[float], None] | None = None,
        on_fault: Callable[[str, str], None] | None = None,
        sensor_timeout_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if set(modes) != {COARSE, FINE}:
            raise ValueError("modes must be exactly 'coarse' and 'fine'")
        self.settings = settings
        self.modes = modes
        self.amplifier = amplifier
        self._clock = clock
        self._sensor_timeout_s = sensor_timeout_s
        self._feed = SensorFeed(sensor, sensor_timeout_s, clock)
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
        self.on_position = on_position
        self.on_fault = on_fault
        self._lock = threading.Lock()
        self._job: Job | None = None
        self._stop_requested = False
        self._stop_reason = ""
        self._shutdown = threading.Event()
        self._thread: threading.Thread | None = None
        self._applied: str | None = None
        self._enabled = False
        self._last_direction: str | None = None
        self.position_m: float | None = None
        self.fault: str | None = None
        self.sensor_lost: str | None = None
        self.last_result: JobResult | None = None
        self._position_saved_s = -math.inf
        self._jitter = collections.deque[float](maxlen=100_000)
        self.ticks = 0
        self.overruns = 0

    # -- public API (any thread) -----------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="control-loop", daemon=True)
        self._thread.start()

    def shutdown(self) -> None:
        """Stop the loop (an active job ends ``stopped``) and close the sensor feed."""
        self.request_stop("daemon shutting down")
        self._shutdown.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._feed.close()

    def busy(self) -> bool:
        with self._lock:
            return self._job is not None

    def submit(self, job: Job) -> str | None:
        """Start ``job``; the reason it is refused, or None when accepted."""
        with self._lock:
            if self.fault is not None:
                return f"in fault state: {self.fault}"
            if self.sensor_lost is not None:
                return f"sensor lost: {self.sensor_lost}"
            if self._job is not None:
                return f"a {self._job.kind} is in progress"
            if job.by_m is not None:
                if self.position_m is None:
                    return "position uncertain: no sensor reading yet for a relative move"
                job.target_m = self.position_m + job.by_m
            if job.target_m is not None:
                s = self.settings
                if not (s.min_position_m <= job.target_m <= s.max_position_m):
                    return (f"target {job.target_m:.6g} m is outside the travel limits "
                            f"[{s.min_position_m:.6g}, {s.max_position_m:.6g}] m")
            self._stop_requested = False
            job.started_s = self._clock()
            if job.on_start is not None:
                job.on_start()
            self._job = job
            return None

    def current_job(self) -> Job | None:
        with self._lock:
            return self._job

    def request_stop(self, reason: str = "stop requested") -> bool:
        """Ask the active job to stop; False when there is none."""
        with self._lock:
            if self._job is None:
                return False
            self._stop_requested = True
            self._stop_reason = reason
            return True

    def replace_amplifier(self, amplifier: Amplifier) -> None:
        """After a reconnect: use the new link and leave the fault state (no move resumes)."""
        with self._lock:
            self.amplifier = amplifier
            self._applied = None
            self._enabled = False
            self.fault = None

    def replace_sensor(self, sensor: PositionSensor) -> None:
        """After a reconnect: read the new sensor; the position is uncertain until it reports."""
        self._feed.close()
        with self._lock:
            self._feed = SensorFeed(sensor, self._sensor_timeout_s, self._clock)
            self.sensor_lost = None
            self.position_m = None

    def estimates(self) -> dict[str, StepEstimate]:
        return {k: e.estimate for k, e in self.estimators.items()}

    def estimates_json(self) -> dict[str, dict[str, float]]:
        """Learned step and burst offset per ``mode/direction`` (m), for replies."""
        return {k: {"step_m": e.step_m, "std_m": e.std_m, "offset_m": e.offset_m,
                    "offset_std_m": e.offset_std_m, "steps": e.steps}
                for k, e in self.estimates().items()}

    def timing(self) -> dict[str, float | int]:
        """Tick jitter p50/p99/max (s), ticks and overruns."""
        jitter = np.array(self._jitter, dtype=float)
        if jitter.size == 0:
            return {"rate_hz": self.settings.rate_hz, "ticks": 0, "overruns": 0,
                    "jitter_p50_s": 0.0, "jitter_p99_s": 0.0, "jitter_max_s": 0.0}
        return {
            "rate_hz": self.settings.rate_hz,
            "ticks": self.ticks,
            "overruns": self.overruns,
            "jitter_p50_s": float(np.percentile(jitter, 50)),
            "jitter_p99_s": float(np.percentile(jitter, 99)),
            "jitter_max_s": float(jitter.max()),
        }

    # -- the loop ----------------------------------------------------------
    def _run(self) -> None:
        period = 1.0 / self.settings.rate_hz
        deadline = self._clock() + period
        while not self._shutdown.is_set():
            delay = deadline - self._clock()
            if delay > 0:
                time.sleep(delay)
            woke = self._clock()
            self._jitter.append(woke - deadline)
            self.ticks += 1
            try:
                self.tick(woke)
            except Exception as err:  # e.g. the state database failing: end the job, keep ticking
                job = self._job
                if job is not None:
                    self._safe_stop()
                    self._finish(job, "fault", f"internal error: {type(err).__name__}: {err}")
            deadline += period
            if self._clock() > deadline:
                self.overruns += 1
                missed = math.floor((self._clock() - deadline) / period) + 1
                deadline += missed * period
        self._finish_on_shutdown()

    def _finish_on_shutdown(self) -> None:
        job = self._job
        if job is not None:
            self._safe_stop()
            self._finish(job, "stopped", "daemon shutting down")

    def tick(self, now: float) -> None:
        """One period of work: sensor, faults, stop requests, the active job's phase."""
        for arrival, sample in self._feed.take():
            self.position_m = sample.position_m
            job = self._job
            if job is not None:
                job.trace.append((arrival, sample.position_m))
                if job.burst is None and arrival >= job.settle_until_s:
                    job.samples.append(sample.position_m)
        if self._feed.lost is not None and self.sensor_lost is None:
            self.sensor_lost = self._feed.lost
            self.position_m = None
            if self._job is not None:
                self._safe_stop()
                self._finish(self._job, "fault", f"sensor lost: {self.sensor_lost}")
            if self.on_fault is not None:
                self.on_fault("sensor", self.sensor_lost)
            return
        job = self._job
        if job is None:
            return
        if (self.on_position is not None and self.position_m is not None
                and now - self._position_saved_s >= self.settings.position_save_s):
            self._position_saved_s = now
            self.on_position(self.position_m)
        try:
            if self._stop_requested:
                self._safe_stop()
                self._finish(job, "stopped", self._stop_reason)
            elif job.burst is not None:
                self._follow_burst(job, now)
            else:
                self._measure(job, now)
        except AmplifierLinkLost as err:
            self._link_lost(job, str(err))
        except AmplifierError as err:
            self._safe_stop()
            self._enabled = False          # the next job checks the output's state again
            self._finish(job, "fault", f"amplifier refused: {err}")
        except Exception as err:  # a driver failing in an unforeseen way: treat as a lost link
            self._link_lost(job, f"{type(err).__name__}: {err}")

    def _link_lost(self, job: Job, message: str) -> None:
        with self._lock:           # fault first: no new job slips in between
            self.fault = f"amplifier link lost: {message}"
        self._finish(job, "fault", self.fault)
        if self.on_fault is not None:
            self.on_fault("amplifier", message)

    def _safe_stop(self) -> None:
        try:
            self.amplifier.stop()
        except AmplifierError as err:
            if isinstance(err, AmplifierLinkLost):
                self._mark_link_lost(str(err))
        except Exception as err:  # see tick()
            self._mark_link_lost(f"{type(err).__name__}: {err}")

    def _mark_link_lost(self, message: str) -> None:
        with self._lock:
            self.fault = f"amplifier link lost: {message}"
        if self.on_fault is not None:
            self.on_fault("amplifier", message)

    def _follow_burst(self, job: Job, now: float) -> None:
        burst = job.burst
        assert burst is not None
        s = self.settings
        if self.position_m is not None and not (s.min_position_m <= self.position_m
                                                <= s.max_position_m):
            self._safe_stop()
            self._finish(job, "limit", f"part seen at {self.position_m:.6g} m, outside the travel"
                         " limits; stopped")
            return
        if now < job.burst_end_s:
            return
        if self.amplifier.status().moving:
            if now > job.burst_end_s + s.burst_grace_s:
                self._safe_stop()
                self._finish(job, "fault", "the amplifier did not finish the burst in time")
            return
        job.burst_end_s = now
        job.settle_until_s = now + s.settle_s
        job.samples = []
        job.burst = None
        job.measured_burst = burst

    def _measure(self, job: Job, now: float) -> None:
        s = self.settings
        if now < job.settle_until_s or len(job.samples) < s.average_samples:
            return
        x = float(np.mean(job.samples[-s.average_samples:]))
        job.samples = []
        if self.on_position is not None:
            self.on_position(x)
        if job.start_m is None:
            job.start_m = x
        if job.measured_burst is not None:
            self._learn(job, job.measured_burst, x)
            job.measured_burst = None
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
        if not self._enabled or self._applied != nxt.mode:
            # leaving ground or changing the amplitude moves the plate's rest position (and
            # the part with it): prepare the output, then measure again before the burst --
            # once; should the decision then change waveform again, step without re-measuring
            # (and without learning from that burst), so the loop cannot ping-pong
            if not self._enabled:
                self._prepare_output()
            if self._applied != nxt.mode:
                self.amplifier.apply(self.modes[nxt.mode].settings)
                self._applied = nxt.mode
                unmeasured_switch = job.switched
            if not unmeasured_switch:
                if job.target_m is None:
                    job.planned.appendleft(nxt)
                job.refined = refined
                job.switched = True
                job.settle_until_s = now + s.settle_s
                return
        job.switched = False
        if job.last_direction is not None and nxt.direction != job.last_direction:
            job.reversals += 1
            if job.reversals > s.max_reversals:
                self._finish(job, "oscillating", f"{job.reversals} direction reversals without "
                             "reaching the tolerance", x)
                return
        self._start_burst(job, nxt, x, now)
        job.burst_learnable = not (job.burst_reversed or unmeasured_switch)

    def _learn(self, job: Job, burst: Burst, x: float) -> None:
        sign = 1.0 if burst.direction == FORWARD else -1.0
        moved = sign * (x - job.burst_from_m)
        est = self.estimators[f"{burst.mode}/{burst.direction}"]
        expected = est.estimate.displacement_m(burst.steps)
        if not job.burst_learnable:  # e.g. after a reversal: may lose up to a step
            expected -= est.estimate.step_m
        if moved < self.settings.stall_fraction * expected:
            job.stalls += 1
            return
        job.stalls = 0
        if job.burst_learnable:
            est.update(burst.steps, moved)

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
        single = fine.estimate.displacement_m(1)       # what one fine step does
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
            burst = Burst(COARSE, direction, min(coarse_steps, s.max_burst_steps))
        else:
            steps = round((distance - fine.estimate.offset_m) / fine.usable_step_m())
            if steps < 1:
                if abs(distance - single) >= distance:
                    return ("unreachable", f"one fine step ({single:.3g} m) cannot reduce the "
                            f"error {error:.3g} m below the tolerance {s.tolerance_m:.3g} m")
                steps = 1
            burst = Burst(FINE, direction, min(steps, s.max_burst_steps))
        return burst

    def _prepare_output(self) -> None:
        """Leave ground for the first burst of a job.

        A latched watchdog fault (a late tick: the firmware grounded itself) is
        cleared, as the new command is the user's; any other fault is reported.
        """
        status = self.amplifier.status()
        if status.fault_word:
            clear = getattr(self.amplifier, "clear_faults", None)
            others = set(status.faults) - CLEARABLE_FAULTS
            if clear is None or others or not status.faults:
                names = ", ".join(status.faults) or hex(status.fault_word)
                raise AmplifierError(f"amplifier fault latched: {names}")
            clear()
        self.amplifier.enable()
        self._enabled = True

    def _start_burst(self, job: Job, burst: Burst, x: float, now: float) -> None:
        mode = self.modes[burst.mode]
        self.amplifier.step(burst.steps if burst.direction == FORWARD else -burst.steps)
        job.burst = burst
        job.burst_from_m = x
        job.burst_reversed = self._last_direction != burst.direction   # None: unknown history
        self._last_direction = burst.direction
        job.burst_end_s = now + burst.steps / mode.settings.frequency_hz
        job.steps += burst.steps
        job.bursts += 1
        job.last_direction = burst.direction

    def _finish(self, job: Job, status: str, reason: str, reached_m: float | None = None) -> None:
        now = self._clock()
        result = JobResult(
            kind=job.kind, status=status, reason=reason, target_m=job.target_m,
            start_m=job.start_m, reached_m=reached_m if reached_m is not None else self.position_m,
            steps=job.steps, bursts=job.bursts,
            duration_s=now - job.started_s,
            estimates=self.estimates_json(),
            trace=job.trace,
        )
        with self._lock:
            self._job = None
            self._stop_requested = False
            self.last_result = result
        job.result = result
        if job.on_done is not None:
            job.on_done(result)
        job.done.set()
