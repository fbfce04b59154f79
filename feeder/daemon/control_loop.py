"""The closed loop's fixed-rate tick: sensor in, policy, commands out (DESIGN §7).

Each tick (default 100 Hz) takes the sensor samples and the executor's
completions that arrived since the last one, feeds them to the
:class:`~feeder.daemon.policy.Policy`, and hands its commands to the
:class:`~feeder.daemon.executor.AmplifierExecutor`, its requests for a
decision to the :class:`~feeder.daemon.decision_worker.DecisionWorker` (whose
answers the policy takes at once, on the worker's thread) and its events to the
:class:`~feeder.daemon.executor.RecordWriter`.  Nothing on the tick's thread
waits for the amplifier, the sensor, the planner or the database: the tick only
moves data between queues, so its jitter is the scheduler's.  Tick jitter (wake-up time
− deadline, :mod:`~feeder.daemon.tick_timing`) and overruns (work that ran past the next
deadline) are counted.

The decisions (what to step, when a move is over) are the policy's, and are
documented there.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np

from feeder import stall
from feeder.daemon.collector import TickCollector
from feeder.daemon.decision_worker import DecisionWorker
from feeder.daemon.executor import AmplifierExecutor, RecordWriter
from feeder.daemon.jobs import (
    Burst,
    Command,
    Decide,
    Decision,
    Fault,
    Finished,
    Job,
    JobResult,
    LoopSettings,
    Output,
    Progress,
    Reading,
    SavePosition,
    Started,
    StepMode,
)
from feeder.daemon.line_navigator import COARSE, FINE
from feeder.daemon.log_throttle import LogThrottle
from feeder.daemon.navigator import Navigator, not_on_plate
from feeder.daemon.policy import Policy
from feeder.daemon.quiet_window import QuietWindow, guard_for
from feeder.daemon.sensor_feed import SensorFeed
from feeder.daemon.step_estimator import StepEstimate
from feeder.daemon.tick_timing import TickLateness, percentile_of_sorted, raise_tick_priority
from feeder.drivers.amplifier import Amplifier
from feeder.drivers.sensor import PositionSample, PositionSensor

__all__ = [
    "COARSE",
    "FINE",
    "Burst",
    "ControlLoop",
    "Job",
    "JobResult",
    "LoopSettings",
    "StepMode",
]

log = logging.getLogger(__name__)

JITTER_WINDOW = 10_000
"""Ticks the jitter figures cover (100 s at 100 Hz): enough for a p99, cheap to sort per status."""


class ControlLoop:
    """Fixed-rate closed loop over one amplifier axis and one position sensor.

    ``modes`` maps ``"coarse"``/``"fine"`` to their :class:`StepMode`;
    ``estimates`` optionally restores learned steps keyed ``"mode/direction"``.
    ``on_position`` is called (on the record writer's thread) with each settled
    position (m) and, during a job, with the latest reading every
    ``position_save_s``; ``on_fault`` with ``("amplifier"|"sensor", message)``
    when a link is lost.  ``collect_in_slack``: the tick runs the interpreter's garbage
    collections after its work (:mod:`~feeder.daemon.collector`); False leaves them to CPython.
    """

    def __init__(
        self,
        amplifier: Amplifier | Mapping[str, Amplifier],
        sensor: PositionSensor,
        modes: dict[str, StepMode],
        settings: LoopSettings | None = None,
        *,
        estimates: dict[str, StepEstimate] | None = None,
        axis_modes: dict[str, dict[str, StepMode]] | None = None,
        navigator: Navigator | None = None,
        on_position: Callable[[float, Reading], None] | None = None,
        on_fault: Callable[[str, str], None] | None = None,
        cause_of_loss: Callable[[], str | None] | None = None,
        sensor_timeout_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        collect_in_slack: bool = True,
    ) -> None:
        settings = settings or LoopSettings()
        self.settings = settings
        self.modes = modes
        self._clock = clock
        self._sensor_timeout_s = sensor_timeout_s
        self.policy = Policy(modes, settings, estimates, axis_modes=axis_modes, navigator=navigator)
        self.executor = AmplifierExecutor(amplifier, self.policy.modes, clock)
        self.decisions = DecisionWorker(self.policy.decide, self._decided)
        self._ending: list[Job] = []  # ended, their records not yet written (_store_unwritable)
        self._ending_lock = threading.Lock()
        self._replacing = threading.Lock()  # replace_sensor's
        self.writer = RecordWriter(on_unwritable=self._store_unwritable, on_writable=self._store_writable)
        self._feed = SensorFeed(sensor, sensor_timeout_s, clock)
        self.on_position = on_position
        self.on_fault = on_fault
        self.cause_of_loss = cause_of_loss
        """What took a lost link with it, when the caller knows (the embedded simulator died)."""
        self._lock = threading.Lock()  # guards the policy between tick and API calls
        self._shutdown = threading.Event()
        self._thread: threading.Thread | None = None
        self.lateness = TickLateness(JITTER_WINDOW)
        """Every tick's lateness (s), the last :data:`JITTER_WINDOW` kept."""
        self.scheduling = "other"
        """The tick thread's scheduling policy: ``fifo`` (real-time) or ``other``."""
        self.overruns = 0
        self._tick_errors = LogThrottle(log)
        self.collector = TickCollector(active=collect_in_slack)
        """Runs the interpreter's garbage collections in the tick's slack while the loop runs."""
        self.quiet = QuietWindow(guard_for(1.0 / settings.rate_hz), clock=clock)
        """Where the daemon's request threads stand back for the tick (:meth:`QuietWindow.hold`)."""

    # -- read-only views -----------------------------------------------------------
    @property
    def amplifier(self) -> Amplifier:
        """The x axis' driver."""
        return self.executor.amplifier

    @property
    def ticks(self) -> int:
        """Ticks run since the start."""
        return self.lateness.count

    @property
    def sensor(self) -> PositionSensor:
        return self._feed.sensor

    def next_sample(self, timeout_s: float) -> PositionSample:
        """The sensor's next sample, for a reader besides the loop (:meth:`SensorFeed.next_sample`)."""
        return self._feed.next_sample(timeout_s)

    @contextlib.contextmanager
    def lent_output(self) -> Iterator[dict[str, Amplifier]]:
        """The amplifiers for a caller alone while no job runs (the caller checks): the policy's
        commands wait meanwhile; afterwards the policy takes every axis as grounded, and the
        next job enables and applies its waveforms again."""
        with self.executor.lent() as amplifiers:
            with self._lock:
                self.policy.output_lent()
            try:
                yield amplifiers
            finally:
                with self._lock:
                    self.policy.output_taken()

    @property
    def amplifiers(self) -> dict[str, Amplifier]:
        """Every axis' driver."""
        return self.executor.amplifiers

    @property
    def reading(self) -> tuple[tuple[float, float, float], ...] | None:
        """Every part's latest pose (m, m, rad), or None while uncertain."""
        return self.policy.reading

    @property
    def position_m(self) -> float | None:
        return self.policy.position_m

    @property
    def fault(self) -> str | None:
        return self.policy.fault

    @property
    def sensor_lost(self) -> str | None:
        return self.policy.sensor_lost

    @property
    def last_result(self) -> JobResult | None:
        return self.policy.last_result

    @property
    def state(self) -> str:
        return self.policy.state

    # -- public API (any thread) -----------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="control-loop", daemon=True)
        self._thread.start()

    def shutdown(self) -> None:
        """Stop the loop (an active job ends ``stopped``), then the executor, feed and writer."""
        self.request_stop("daemon shutting down")
        deadline = time.monotonic() + self.settings.hold_timeout_s + 1.0
        while self.busy() and self._thread is not None and time.monotonic() < deadline:
            time.sleep(0.01)
        self._shutdown.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        job = self.current_job()
        if job is not None:  # the loop did not get to finish it: say so
            self._dispatch(
                [
                    Finished(
                        job,
                        JobResult(
                            job.kind,
                            "stopped",
                            "daemon shutting down",
                            job.target_m,
                            job.start_m,
                            self.position_m,
                            job.steps,
                            job.bursts,
                            0.0,
                            self.estimates_json(),
                            job.trace,
                        ),
                    )
                ]
            )
        self.decisions.close()
        self.executor.close()
        self._feed.close()
        self.writer.close()

    def busy(self) -> bool:
        with self._lock:
            return self.policy.job is not None

    def submit(self, job: Job) -> str | None:
        """Start ``job``; the reason it is refused, or None when accepted."""
        with self._lock:
            reason = self.policy.submit(job, self._clock())
            outputs = self.policy.tick(self._clock()) if reason is None else []
        self._dispatch(outputs)
        return reason

    def current_job(self) -> Job | None:
        with self._lock:
            return self.policy.job

    def request_stop(self, reason: str = "stop requested") -> bool:
        """Ask the active job to stop; False when there is none."""
        with self._lock:
            return self.policy.request_stop(reason)

    def amplifier_lost(self, message: str) -> None:
        """Declare the amplifier link lost (the job ends, ``on_fault`` reconnects)."""
        with self._lock:
            self.policy.on_link_lost(self._blamed(message))
            outputs = self.policy.tick(self._clock())
        self._dispatch(outputs)

    def _blamed(self, message: str) -> str:
        """A lost link's ``message``, led by what took it with it (the simulator died: its camera
        and console went with it, and the camera's silence was noticed first)."""
        cause = self.cause_of_loss() if self.cause_of_loss is not None else None
        return message if cause is None else f"{cause}: {message}"

    def _decided(self, decision: Decision) -> None:
        """The navigator's answer (on the decision worker's thread): acted on now, not a period later."""
        with self._lock:
            self.policy.on_decision(decision)
            outputs = self.policy.tick(self._clock())
        self._dispatch(outputs)

    def replace_amplifier(self, amplifier: Amplifier | Mapping[str, Amplifier]) -> None:
        """After a reconnect: use the new link and leave the fault state (no move resumes)."""
        self.executor.replace(amplifier)
        self.executor.take()  # completions of the old link are void
        with self._lock:
            self.policy.link_restored()

    def replace_sensor(self, sensor: PositionSensor, first: PositionSample | None = None) -> None:
        """After a reconnect: read the new sensor (``first``: the reading that showed it works);
        the position is uncertain until it reports.  One replacement at a time: two at once (a
        recalibration and a reconnect) both closed the same old feed, and the second orphaned
        the first's new one, its reader never closed."""
        with self._replacing:
            self._feed.close()
            feed = SensorFeed(sensor, self._sensor_timeout_s, self._clock, first)
            with self._lock:
                self._feed = feed
                self.policy.sensor_restored()

    def estimates(self) -> dict[str, StepEstimate]:
        with self._lock:
            return self.policy.navigator.estimates()

    def release(self, part: int | None = None) -> list[int] | str:
        """Let held parts go (the navigator's :meth:`release`): the ids released, or why not."""
        with self._lock:
            if self.policy.job is not None:
                return "a move is running: release held parts once it has ended (or stop it)"
            reading = self.policy.reading
            missing = None if part is None or not reading else not_on_plate(part, reading)
            if missing is not None:
                return missing
            return self.policy.navigator.release(part)

    def holds(self) -> list[dict[str, Any]]:
        """The parts later moves keep at their targets, with those targets."""
        with self._lock:
            return self.policy.navigator.holds()

    def estimates_json(self) -> dict[str, Any]:
        """Learned step and burst offset per ``mode/direction`` (m), for replies."""
        with self._lock:
            return self.policy.navigator.estimates_json()

    def timing(self) -> dict[str, float | int | str]:
        """Tick jitter p50/p99/max (s), ticks and overruns, the tick's scheduling policy; the
        navigator's last and longest decision (s, off the tick); the garbage collections in the
        slack; how often a request thread stood back for the tick."""
        jitter = np.sort(self.lateness.last(JITTER_WINDOW))
        figures = {"ticks": 0, "overruns": 0, "jitter_p50_s": 0.0, "jitter_p99_s": 0.0, "jitter_max_s": 0.0}
        if jitter.size:
            figures = {
                "ticks": self.ticks,
                "overruns": self.overruns,
                "jitter_p50_s": percentile_of_sorted(jitter, 50),
                "jitter_p99_s": percentile_of_sorted(jitter, 99),
                "jitter_max_s": float(jitter[-1]),
            }
        return {
            "rate_hz": self.settings.rate_hz,
            "scheduling": self.scheduling,
            **figures,
            "decision_last_s": self.decisions.last_s,
            "decision_max_s": self.decisions.longest_s,
            "collections": self.collector.collections,
            "collection_max_s": self.collector.longest_s,
            "quiet_holds": self.quiet.holds,
        }

    # -- the loop ----------------------------------------------------------------------
    def _run(self) -> None:
        self.scheduling = raise_tick_priority()
        self.collector.take_over()
        try:
            self._tick_until_shutdown()
        finally:
            self.quiet.served()
            self.collector.hand_back()

    def _tick_until_shutdown(self) -> None:
        period = 1.0 / self.settings.rate_hz
        deadline = self._clock() + period
        while not self._shutdown.is_set():
            self.quiet.due(deadline)
            delay = deadline - self._clock()
            cpu = time.process_time()
            if delay > 0:
                time.sleep(delay)
            woke = self._clock()
            self.lateness.append(woke - deadline)
            if woke - deadline > stall.GAP_S:
                log.warning("the control loop ran %.2f s late: %s", woke - deadline,
                            stall.why_late(woke - deadline, time.process_time() - cpu))  # fmt: skip
            self._tick_guarded(woke)
            self.quiet.served()
            self.collector.collect_due()  # in the slack the tick leaves, not before a deadline
            deadline += period
            if self._clock() > deadline:
                self.overruns += 1
                missed = math.floor((self._clock() - deadline) / period) + 1
                deadline += missed * period

    def _tick_guarded(self, now: float) -> None:
        """:meth:`tick`, within the tick thread's one boundary: an unexpected error in it (a bug)
        is taken as a lost amplifier link (the job ends ``fault``, every axis is grounded, the
        link reopened), never the loop's end: a dead tick left an axis driven and every later
        stop unanswered."""
        try:
            self.tick(now)
        except Exception as err:  # the tick thread's one boundary (the docstring)
            with self._lock:
                first = self.policy.fault is None
                outputs = self.policy.on_internal_error(f"control loop error: {type(err).__name__}: {err}")
            if first:
                log.exception("control loop: a tick failed; taken as a lost amplifier link")
            else:
                self._tick_errors.warning("control loop: a tick failed again (%r)", err)
            self._dispatch(outputs)

    def tick(self, now: float) -> None:
        """One period: move samples and completions into the policy, its outputs out."""
        for amplifier in self.executor.amplifiers.values():  # the loop makes progress: the
            amplifier.alive()  # drive's host watchdog keeps hearing us (a timestamp each)
        with self._lock:  # the feed with the lock: a replaced one's loss is not the new one's
            feed = self._feed
            for arrival, sample in feed.take():
                self.policy.on_sample(sample.position_m, arrival, sample.poses)
            if feed.lost is not None:
                self.policy.on_sensor_lost(self._blamed(feed.lost))
            for completion in self.executor.take():
                if completion.link_lost and completion.error is not None:
                    completion = dataclasses.replace(completion, error=self._blamed(completion.error))
                self.policy.on_completion(completion)
            outputs = self.policy.tick(now)
        self._dispatch(outputs)

    def _dispatch(self, outputs: list[Output]) -> None:
        for out in outputs:
            if isinstance(out, Command):
                self.executor.submit(out)
            elif isinstance(out, Decide):
                self.decisions.submit(out)
            elif isinstance(out, Started):
                self.writer.put(functools.partial(self._record_start, out.job))
            elif isinstance(out, Finished):
                out.job.result = out.result
                with self._ending_lock:
                    self._ending.append(out.job)
                if self.writer.unwritable is not None:  # the caller learns now; the record
                    out.job.done.set()  # follows when it can (an outage later: _store_unwritable)
                self.writer.put(functools.partial(self._record_end, out.job, out.result))
            elif isinstance(out, Progress):
                if out.job.on_progress is not None:
                    self.writer.put(out.job.on_progress)
            elif isinstance(out, SavePosition):
                if self.on_position is not None:
                    self.writer.put(functools.partial(self.on_position, out.position_m, out.poses))
            elif isinstance(out, Fault):
                log.warning("%s link lost: %s", out.link, out.message)
                if self.on_fault is not None:  # it grounds and reconnects: not on the tick
                    threading.Thread(
                        target=self.on_fault, args=(out.link, out.message), name="on-fault", daemon=True
                    ).start()

    def _store_unwritable(self, message: str) -> None:
        """The state store cannot be written: end the move, refuse moves until it can, and answer
        the moves that ended with their records still to write (behind the failing one: their
        callers had waited as long as the outage lasted)."""
        with self._lock:
            self.policy.store_unwritable = f"state store unwritable: {message}"
            self.policy.request_stop(self.policy.store_unwritable)
        with self._ending_lock:
            ending, self._ending = self._ending, []
        for job in ending:
            job.done.set()

    def _store_writable(self) -> None:
        with self._lock:
            self.policy.store_unwritable = None

    @staticmethod
    def _record_start(job: Job) -> None:
        try:
            if job.on_start is not None:
                job.on_start()
        finally:
            job.recorded = True

    def _record_end(self, job: Job, result: JobResult) -> None:
        try:
            if job.on_done is not None:
                job.on_done(result)
        finally:
            job.done.set()
            with self._ending_lock:
                self._ending = [each for each in self._ending if each is not job]
