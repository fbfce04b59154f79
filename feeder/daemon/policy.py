"""The closed loop as an explicit state machine: measurements in, commands out.

No I/O, no threads, no sleeps: :class:`Policy` is fed sensor readings, the
executor's completions and the time, and answers with
:class:`~feeder.daemon.jobs.Command`s for the amplifier and events for the
record.  :mod:`feeder.daemon.control_loop` runs it on a fixed-rate tick and
does the I/O; the unit tests drive it with a fake clock.  *Where* to step is a
navigator's decision: :class:`~feeder.daemon.line_navigator.LineNavigator`
along one axis, :class:`~feeder.daemon.pose_navigator.PoseNavigator` in x, y
and θ; the policy only measures, steps, stops and records.

States (:data:`STATES`):

- ``idle``: no job; a done move left every axis grounded, and ``idle_ground_s`` after any
  other end every axis is grounded (a :class:`~feeder.daemon.jobs.Command` ``ground``): a
  real ANC300 keeps its axes driven until told otherwise, whatever becomes of the host.
- ``moving``: a job is preparing the output or a burst is playing.
- ``settling``: the burst is over; wait until the part may be measured
  (:mod:`feeder.daemon.burst_cycle`: ``settle_s`` or the sensor's latency as seen,
  fresh readings that agree, at least two, the burst's motion seen), measure;
  learn, decide.  The navigator decides off the tick: the policy emits a
  :class:`~feeder.daemon.jobs.Decide`, the loop runs :meth:`Policy.decide` on a thread
  of its own, and the answer comes back through :meth:`Policy.on_decision` (one
  answered after the job ended is dropped).
- ``holding``: the job is over early (a stop, a limit, a command the amplifier
  refused): the output was stopped and the part is watched until the sensor
  reads it settled (the last readings, at least two, agree within the
  tolerance); only then is the result, with the settled position and the
  steps actually played, final.
- ``fault``: the amplifier link or the sensor is lost; no job is accepted
  until the link is restored (:meth:`Policy.link_restored`, :meth:`Policy.sensor_restored`).

A move alternates *measure* and *burst*.  Leaving ground or changing an axis' waveform
moves the plate's rest position, so the loop measures again after it (once per burst).
The navigator's ``done`` is checked grounded (an axis at rest holds its waveform's level;
grounding it moves the plate by that stroke): ground, measure, and step on from there if
out of tolerance (:data:`MAX_GROUND_CHECKS`).  A move ends on request (``stopped``), on
stall, on travel limits, on too many reversals, on a lost sensor or link (``fault``), or
when the navigator says it is over (``done``, ``unreachable``).
"""

from __future__ import annotations

import math

from feeder.daemon.burst_cycle import BurstCycle
from feeder.daemon.jobs import (
    Burst,
    Command,
    Completion,
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
from feeder.daemon.line_navigator import LineNavigator
from feeder.daemon.navigator import Navigator, part_pose
from feeder.daemon.step_estimator import StepEstimate
from feeder.reading_noise import RestingNoise

STATES = ("idle", "moving", "settling", "holding", "fault")

MAX_GROUND_CHECKS = 4
"""A move is done when its parts are within tolerance with every axis grounded; after this many
grounds that found them out of it again, it ends ``unreachable`` (docs/daemon.md: 2 were too few)."""


class Policy:
    """The loop's state machine (the module docstring).  modes: the x axis' ``"coarse"``/``"fine"``
    :class:`StepMode`; axis_modes: every axis' modes (``"x"``, ``"y"``, ``"theta"``) when the loop
    drives more than x; navigator: where to step (default: a :class:`LineNavigator` on ``modes``,
    restoring ``estimates``)."""

    def __init__(
        self,
        modes: dict[str, StepMode],
        settings: LoopSettings,
        estimates: dict[str, StepEstimate] | None = None,
        *,
        axis_modes: dict[str, dict[str, StepMode]] | None = None,
        navigator: Navigator | None = None,
    ) -> None:
        self.modes = axis_modes or {"x": modes}
        self.settings = settings
        self.navigator: Navigator = navigator or LineNavigator(modes, settings, estimates)
        missing = set(self.navigator.axes) - set(self.modes)
        if missing:
            raise ValueError(f"no waveform modes for axes {sorted(missing)}")
        self.state = "idle"
        self.job: Job | None = None
        self.reading: Reading | None = None
        self.fault: str | None = None
        self.sensor_lost: str | None = None
        self.store_unwritable: str | None = None  # set by the loop while records cannot be written
        self.last_result: JobResult | None = None
        self._stop_reason: str | None = None
        self._pending: Command | None = None  # sent, not yet completed
        self._cycle = BurstCycle(self.modes, settings, self.navigator)
        self._applied: dict[str, str] = {}  # axis → mode loaded
        self._enabled = False
        self._deciding: Decide | None = None  # asked, not yet answered
        self._decision: Decision | None = None  # answered, to act on at the next tick
        self._finish_as: tuple[str, str] | None = None  # (status, reason) once held
        self._hold_until = 0.0
        self._position_saved_s = -math.inf
        self._idle_until = math.inf  # when the output is grounded if no job comes
        self._grounded = True  # every axis known grounded (the daemon grounds them at start)
        self._lent = False  # the output driven outside the policy (offset moves)
        self._checking_ground = False  # grounded to check a done pose: measure without enabling
        self.resting_noise = RestingNoise()
        self._now = 0.0
        self._out: list[Output] = []

    @property
    def latency_s(self) -> float:
        """The sensor's latency as seen (s; :class:`~feeder.daemon.sensor_latency.SensorLatency`)."""
        return self._cycle.latency_s

    def applied(self, axis: str) -> str | None:
        """The waveform mode loaded on ``axis`` (None: none since the link opened)."""
        return self._applied.get(axis)

    @property
    def position_m(self) -> float | None:
        """The first part's x (m), or None while the position is uncertain."""
        return None if self.reading is None else self.reading[0][0]

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
        if job.target_m is not None or job.by_m is not None or job.pose_target is not None:
            refused = self.navigator.prepare(job, self.reading)
            if refused is not None:
                return refused
        job.started_s = self._now = now
        self.job = job
        self._idle_until = math.inf
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

    def on_sample(self, position_m: float, arrival_s: float, poses: Reading = ()) -> None:
        """A sensor reading that arrived at loop time ``arrival_s``: every part's pose, or
        (a one-axis sensor) the position along x (m)."""
        reading = poses or ((position_m, 0.0, 0.0),)
        self.reading = reading
        job = self.job
        if job is None and self.state == "idle" and self._pending is None and not self._lent:
            self.resting_noise.add([c for x, y, _ in poses for c in (x, y)] if poses else [position_m])
        else:
            self.resting_noise.restart()
        if job is None:
            return
        part = part_pose(job, reading)
        job.trace.append((arrival_s, part[0]))
        if job.target_pose is not None:
            job.pose_trace.append((arrival_s, part))
        self._cycle.on_sample(reading, arrival_s, self.state)

    def on_sensor_lost(self, message: str) -> None:
        if self.sensor_lost is not None:
            return
        self.sensor_lost = message
        self.reading = None
        self._out.append(Fault("sensor", message))
        if self.job is not None:
            self._emit_stop()
            self._finish(self.job, "fault", f"sensor lost: {message}", None)
        self._out.append(Command("ground"))  # blind: every axis to ground, after the stop
        self._enabled = False
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
            elif kind in ("stop", "ground"):  # the output may still play: such a link is lost
                self._link_lost(f"the amplifier refused {kind}: {done.error}")
            else:
                self._enabled = False  # the next job checks the output's state again
                self._applied = {}
                if self.job is not None and self._finish_as is None:
                    # a burst whose end was not confirmed may still play: stop it and end the
                    # job once the part reads settled, as after a stop (not with a pose the
                    # part is still leaving, the daemon idle while it moves)
                    self._end_early("fault", f"amplifier refused: {done.error}", done.at_s)
            return
        burst = self._cycle.flying
        if kind == "ground":
            self._grounded = True
            if self._checking_ground and self.job is not None and self._finish_as is None:
                self._enter_settling(done.at_s)  # measure the pose the grounded axes leave
        if kind in ("enable", "apply"):
            if kind == "enable":
                self._enabled = True
            else:
                self._applied[done.command.axis] = done.command.mode
            if burst is None and self.job is not None and self._finish_as is None:
                self._enter_settling(done.at_s)  # the plate's rest moved: measure again
        elif kind == "step" and burst is not None:
            self._cycle.acknowledged(done.at_s, done.counter)
        elif kind == "confirm_end" and burst is not None:
            self.state = "settling"
            self._cycle.ended(done.at_s)
        elif kind == "stop":
            if burst is not None and self.job is not None:
                self.job.steps -= self._cycle.unplayed(done.counter)
                self.job.steps_estimated = self.job.steps_estimated or done.estimated
            if self.job is not None and self._finish_as is not None:
                self._enter_holding(done.at_s)

    def decide(self, request: Decide) -> Decision:
        """The navigator's answer to ``request`` (run by the loop off the tick, on any thread:
        it touches the navigator only)."""
        return Decision(request, self.navigator.next_burst(request.job, request.reading))

    def on_decision(self, decision: Decision) -> None:
        """The answer to the last :class:`Decide`, acted on at the next :meth:`tick` (the loop
        calls it at once); dropped when the job ended or stopped meanwhile."""
        if decision.request is self._deciding:
            self._deciding = None
            self._decision = decision

    def on_link_lost(self, message: str) -> None:
        """The amplifier link is known to be gone (e.g. the simulator behind it restarted)."""
        if self.fault is None:
            self._link_lost(message)

    def on_internal_error(self, message: str) -> list[Output]:
        """An error of the loop's own (a bug), taken as a lost amplifier link: the job ends
        ``fault`` and the daemon grounds every axis and reconnects; the outputs to dispatch."""
        if self.fault is None:
            self._link_lost(message)
        out, self._out = self._out, []
        return out

    def link_restored(self) -> None:
        """A new amplifier link (grounded): leave the fault state; no move resumes."""
        self.fault = None
        self._applied = {}
        self._enabled = False
        self._grounded = True  # the new link was grounded
        self._pending = None
        if self.sensor_lost is None:
            self.state = "idle"

    def output_lent(self) -> None:
        """The axes are driven outside the policy from now on (a camera calibration's offset
        moves): the parts are not at rest (:attr:`resting_noise`) until :meth:`output_taken`."""
        self._lent = True

    def output_taken(self) -> None:
        """The axes were driven outside the policy (a camera calibration's offset moves) and
        left grounded: the next job enables and applies its waveforms again."""
        self._lent = False
        self._applied = {}
        self._enabled = False
        self._grounded = True
        self._idle_until = math.inf

    def sensor_restored(self) -> None:
        """A new sensor link: the position is uncertain until it reports."""
        self.sensor_lost = None
        self.reading = None
        self.resting_noise = RestingNoise()  # another sensor's, perhaps
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
            elif self._cycle.flying is not None:  # its travel watched also while its end is confirmed
                self._follow_burst(now)
            elif self._pending is None:
                if self._decision is not None:
                    self._decided(job, self._decision)
                elif self._deciding is None:
                    self._measure(job, now)
        elif job is None and self._pending is None and now >= self._idle_until:
            self._ground_idle()
        out, self._out = self._out, []
        return out

    # -- internals ---------------------------------------------------------------------

    def _send(self, command: Command) -> None:
        self._pending = command
        self._out.append(command)

    def _ground_idle(self) -> None:
        """No move followed the last one: every axis to ground (the next move enables again and
        measures, the plate's rest having moved)."""
        self._idle_until = math.inf
        if not self._grounded and self.fault is None and self.sensor_lost is None:
            self._enabled = False
            self._send(Command("ground"))

    def _emit_stop(self) -> bool:
        """Stop the output now if anything may be playing (jumps any command in flight); whether
        a stop was sent."""
        playing = self._cycle.flying is not None or self._pending is not None
        if playing:
            self._out.append(self._cycle.stop_command())
        return playing

    def _end_early(self, status: str, reason: str, now: float) -> None:
        """End the job with ``status`` once the output stopped and the part settled."""
        self._finish_as = (status, reason)
        self._deciding = self._decision = None
        if not self._emit_stop():  # else holding starts when the stop is done
            self._enter_holding(now)

    def _link_lost(self, message: str) -> None:
        self.fault = f"amplifier link lost: {message}"
        self._pending = None
        self._out.append(Fault("amplifier", message))
        if self.job is not None:
            self._finish(self.job, "fault", self.fault, None)
        self.state = "fault"

    def _save_position(self, now: float) -> None:
        if self.reading is not None and now - self._position_saved_s >= self.settings.position_save_s:
            self._position_saved_s = now
            self._out.append(SavePosition(self.reading[0][0], self.reading))

    def _enter_settling(self, now: float, settle: bool = True) -> None:
        self.state = "settling"
        self._cycle.watch(now, settle)

    def _enter_holding(self, now: float) -> None:
        self.state = "holding"
        self._cycle.watch(now)
        self._hold_until = now + self.settings.hold_timeout_s

    def _hold(self, job: Job, now: float) -> None:
        """Watch the stopped part until the sensor reads it settled, then finish."""
        s = self.settings
        assert self._finish_as is not None
        status, reason = self._finish_as
        reading = self._cycle.settled()
        if reading is not None:
            self._out.append(SavePosition(reading[0][0], reading))
            self._finish(job, status, reason, reading)
        elif now >= self._hold_until:
            reason += f"; the part did not settle within {s.hold_timeout_s:g} s after the output stopped"
            self._finish(job, status, reason, self.reading)

    def _follow_burst(self, now: float) -> None:
        if self.reading is not None and self.navigator.outside(self.reading) is not None:
            self._end_early("limit", f"{self.navigator.outside(self.reading)}; stopped", now)
            return
        confirm = self._cycle.confirmation(now)
        if confirm is not None:
            self._send(confirm)

    def _measure(self, job: Job, now: float) -> None:
        if not job.recorded:
            return  # the record comes first: a crash leaves a trace
        if not self._enabled and not self._checking_ground:
            self.state = "moving"
            self._grounded = False  # from the enable on, until a ground is acknowledged
            self._send(Command("enable"))
            return
        reading = self._cycle.measure(job, now)
        if reading is None:
            return
        self._out.append(SavePosition(reading[0][0], reading))
        nxt = self._cycle.verdict(job, reading)
        if nxt is None:  # the navigator's turn, off the tick
            self._deciding = Decide(job, reading, job.refined)
            self._out.append(self._deciding)
            return
        self._start_burst(job, reading, nxt, job.refined)

    def _decided(self, job: Job, decision: Decision) -> None:
        self._decision = None
        self._start_burst(job, decision.request.reading, decision.answer, decision.request.refined)

    def _start_burst(self, job: Job, reading: Reading, nxt: Burst | tuple[str, str], refined: bool) -> None:
        """Play ``nxt`` decided from ``reading`` (first loading its waveform), or finish as it says;
        ``refined``: the job's flag before the decision."""
        if isinstance(nxt, tuple):
            self._conclude(job, reading, *nxt)
            return
        # after the ground that checked a done pose: enable and step from that pose (measured
        # again once enabled, the pose would be the one the driven axes give, done again)
        unmeasured = unmeasured_switch = not self._enabled
        if unmeasured:
            self._checking_ground = self._grounded = False
            self._send(Command("enable"))
        if self._applied.get(nxt.axis) != nxt.mode:
            # changing the amplitude moves the plate's rest position (and the part with it):
            # apply, then measure again before the burst -- once; should the decision then
            # change waveform again, step without re-measuring (and without learning)
            unmeasured_switch = job.switched or unmeasured
            if job.target_m is None and job.target_pose is None:
                job.planned.appendleft(nxt)
            job.refined = refined
            job.switched = True
            self.state = "moving"
            self._send(Command("apply", mode=nxt.mode, axis=nxt.axis))
            if not unmeasured_switch:
                return  # measure again once it is applied
            if job.target_m is None and job.target_pose is None:
                job.planned.popleft()
        job.switched = False
        step = self._cycle.start(job, nxt, reading, unmeasured_switch, grounded=unmeasured)
        if isinstance(step, tuple):
            self._finish(job, *step, reading)
            return
        self.state = "moving"
        # (after an unmeasured switch the apply is still in flight: the executor runs both
        # in order, and the step is what the policy waits for)
        self._send(step)
        self._out.append(Progress(job))

    def _conclude(self, job: Job, reading: Reading, status: str, reason: str) -> None:
        """Finish ``job`` as the navigator or the cycle says.  A done pose is the one the grounded
        axes leave (an axis at rest holds its waveform's level, an ANC300 the top of its table
        after backward steps, and grounding it moves the plate and a part stuck to it): ground
        and measure again first."""
        if status == "done" and (job.target_m is not None or job.target_pose is not None):
            if self._grounded:
                self.navigator.reached(job, reading)
            elif job.ground_checks < MAX_GROUND_CHECKS:
                job.ground_checks += 1
                self._checking_ground, self._enabled, self.state = True, False, "settling"
                self._send(Command("ground"))
                return
            else:
                status = "unreachable"
                reason = (f"within tolerance while the axes were driven, not once they were grounded "
                          f"({job.ground_checks} tries: their rest level moves the part)")  # fmt: skip
        self._finish(job, status, reason, reading)

    def _finish(self, job: Job, status: str, reason: str, reached: Reading | None) -> None:
        now = self._now
        reached = reached if reached is not None else self.reading
        pose = None if reached is None else part_pose(job, reached)
        result = job.ended(status, reason, pose, now, self.navigator.estimates_json(),
                           getattr(self.navigator, "symmetry_rad", 0.0))  # fmt: skip
        self.job = None
        self._cycle.clear()
        self._pending = None
        self._deciding = self._decision = None
        self._finish_as = None
        self._stop_reason = None
        self._checking_ground = False
        self.last_result = result
        if self.fault is None and self.sensor_lost is None:
            self.state = "idle"
            # enabled, or unknown (a refused command may have left any axis in stp): ground
            self._idle_until = now + self.settings.idle_ground_s if not self._grounded else math.inf
        self._out.append(Finished(job, result))
