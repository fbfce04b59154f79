"""What the closed loop works on: jobs, bursts, commands to the amplifier and events for the record.

Plain data shared by the policy (:mod:`feeder.daemon.policy`), its navigators
and the loop that does the I/O.  Lengths in m, angles in rad, times in s.
"""

from __future__ import annotations

import collections
import math
import threading  # a Job's done event only: the policy never waits on it
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from feeder.daemon.step_estimator import StepEstimate
from feeder.drivers.amplifier import DriveSettings
from feeder.pose import Pose, pose_error

Reading = tuple[Pose, ...]
"""Every part's pose (m, m, rad) at one instant; a one-axis sensor gives ((x, 0, 0),)."""


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


VISIBLE_BANDS = 3.0
"""A burst expected to move a part by this many settle bands (m; or tolerances, rad) must show
its motion in the frames before it is measured (:meth:`~feeder.daemon.navigator.Navigator.expects_motion`)."""


@dataclass(frozen=True)
class LoopSettings:
    """Tuning of the loop; lengths in m, angles in rad, times in s.  The travel is
    [min_position_m, max_position_m] in x and [min_y_m, max_y_m] in y (plate frame)."""

    rate_hz: float = 100.0
    tolerance_m: float = 1e-6
    tolerance_rad: float = 1.7453292519943296e-3  # 0.1°
    min_position_m: float = -10e-3
    max_position_m: float = 10e-3
    min_y_m: float = -10e-3
    max_y_m: float = 10e-3
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
    idle_ground_s: float = 2.0
    """The output is grounded when no move followed the last one within this time: a real
    ANC300 keeps its axes driven until told otherwise and has no host watchdog."""

    @property
    def settle_band_m(self) -> float:
        """Readings this close agree: the part settled in them (the tolerance, or six sensor σ)."""
        return max(self.tolerance_m, 6 * self.sensor_noise_m)


@dataclass(frozen=True)
class Burst:
    """One burst of a job: ``steps`` > 0 in ``direction`` with ``axis``' waveform ``mode``;
    ``path``: a leg of a planned path, whose reversal is not counted
    (:attr:`~feeder.pose_burst.AxisBurst.path`)."""

    mode: str
    direction: str
    steps: int
    axis: str = "x"
    path: bool = False


# -- commands to the executor, and what it reports back --------------------------------


@dataclass(frozen=True)
class Command:
    """An amplifier action for the executor (``kind``: see :data:`COMMANDS`)."""

    kind: str
    mode: str = ""
    steps: int = 0
    timeout_s: float = 0.0
    axis: str = "x"


COMMANDS = ("enable", "apply", "step", "confirm_end", "stop", "ground")
"""enable: leave ground on every axis (clearing a latched transient fault); apply: load a
mode's waveform on ``axis``; step: start a burst of ``steps`` (signed) on ``axis``;
confirm_end: check the burst on ``axis`` is over (``stepw``); stop: stop every axis now
(the counter reported is ``axis``'); ground: every axis to ground (the next job enables)."""


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
    (a drive that counts none, e.g. the ANC300).  A pose move (``target_pose``
    set) also gives the part, its start and reached poses, ``pose_trace``
    ((loop time s, pose)) and the errors: ``error_m`` the distance of the
    centre from the target, ``error_rad`` the angle difference modulo the
    part's symmetry (None when any angle would do: ``angle_free``).
    ``target_m``/``start_m``/``reached_m`` are the part's x.
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
    part: int = 1
    target_pose: Pose | None = None
    start_pose: Pose | None = None
    reached_pose: Pose | None = None
    symmetry_rad: float = 0.0
    pose_trace: list[tuple[float, Pose]] = field(default_factory=list)
    bursts_per_axis: dict[str, int] = field(default_factory=dict)
    angle_free: bool = False

    @property
    def error_m(self) -> float | None:
        """Pose move: distance of the centre from the target (≥ 0); else reached − target along x."""
        if self.target_pose is not None:
            if self.reached_pose is None:
                return None
            return pose_error(self.reached_pose, self.target_pose, self.symmetry_rad)[0]
        if self.target_m is None or self.reached_m is None:
            return None
        return self.reached_m - self.target_m

    @property
    def error_rad(self) -> float | None:
        """Pose move: |angle difference| modulo the part's symmetry; else (or any angle) None."""
        if self.target_pose is None or self.reached_pose is None or self.angle_free:
            return None
        return pose_error(self.reached_pose, self.target_pose, self.symmetry_rad)[1]

    def reached_on_branch(self) -> Pose:
        """The reached pose, its angle on the target's branch: a part of symmetry s looks the same
        turned by s, so the camera's angle is taken within ±s/2 of the target's (as is ``error_rad``)."""
        assert self.reached_pose is not None
        x, y, psi = self.reached_pose
        if self.target_pose is None or self.angle_free or self.symmetry_rad <= 0:
            return self.reached_pose
        target = self.target_pose[2]
        return (x, y, target + math.remainder(psi - target, self.symmetry_rad))

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
        if self.target_pose is not None:
            x, y, psi = self.target_pose
            out.update(
                part=self.part,
                target_pose=[x, y, None if self.angle_free else psi],  # None: any angle
                start_pose=None if self.start_pose is None else list(self.start_pose),
                pose=None if self.reached_pose is None else list(self.reached_on_branch()),
                error_rad=self.error_rad,
                angle_free=self.angle_free,
                bursts_per_axis=self.bursts_per_axis,
            )
        if with_trace:
            out["trace"] = [[t, x] for t, x in self.trace]
            if self.target_pose is not None:
                out["pose_trace"] = [[t, *p] for t, p in self.pose_trace]
        return out


class Job:
    """A move to ``target_m`` (or by ``by_m`` from where the part is when it starts), a move of
    part ``part`` to a pose (``pose_target``: any of ``x_m``, ``y_m``, ``angle_rad``; what is
    missing keeps the part's value at the start, except an angle beside a held part: any),
    or a calibration sequence of fixed bursts.
    ``on_start`` runs when the loop accepts it (the record is written before the first step:
    the loop sets ``recorded``); ``on_done`` with the result at the end, then ``done`` is set.
    The policy only reads and writes the progress fields; the callbacks and ``done`` belong to the loop."""

    def __init__(
        self,
        kind: str,
        target_m: float | None = None,
        bursts: tuple[Burst, ...] = (),
        *,
        by_m: float | None = None,
        pose_target: dict[str, float] | None = None,
        part: int = 1,
        on_start: Callable[[], None] | None = None,
        on_done: Callable[[JobResult], None] | None = None,
        on_progress: Callable[[], None] | None = None,
    ) -> None:
        self.kind = kind
        self.target_m = target_m
        self.by_m = by_m
        self.pose_target = pose_target
        self.part = part
        self.target_pose: Pose | None = None  # resolved when the loop accepts it
        self.angle_free = False  # the target's angle is any angle (beside a held part)
        self.angle_asked = False  # the request gave an angle (a hold keeps it)
        self.planned = collections.deque(bursts)
        self.on_start = on_start
        self.on_done = on_done
        self.on_progress = on_progress
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
        self.ground_checks = 0  # grounds to check a done pose (Policy._conclude)
        self.last_directions: dict[str, str] = {}  # axis → direction of its last burst in this job
        self.trace: list[tuple[float, float]] = []
        self.pose_trace: list[tuple[float, Pose]] = []
        self.start_pose: Pose | None = None
        self.bursts_per_axis: dict[str, int] = {}
        self.steps_estimated = False

    def ended(self, status: str, reason: str, reached: Pose | None, now_s: float,
              estimates: dict[str, dict[str, float]], symmetry_rad: float) -> JobResult:  # fmt: skip
        """Its result: ended with ``status`` at loop time ``now_s``, the part at ``reached``."""
        return JobResult(
            kind=self.kind,
            status=status,
            reason=reason,
            target_m=self.target_m,
            start_m=self.start_m,
            reached_m=None if reached is None else reached[0],
            steps=self.steps,
            bursts=self.bursts,
            duration_s=max(0.0, now_s - self.started_s),
            estimates=estimates,
            trace=self.trace,
            steps_estimated=self.steps_estimated,
            part=self.part,
            target_pose=self.target_pose,
            start_pose=self.start_pose,
            reached_pose=reached,
            symmetry_rad=symmetry_rad,
            pose_trace=self.pose_trace,
            bursts_per_axis=self.bursts_per_axis,
            angle_free=self.angle_free,
        )


@dataclass(frozen=True)
class Started:
    """Event: write the job's record (``job.on_start``), then mark it recorded."""

    job: Job


@dataclass(frozen=True)
class Progress:
    """Event: a burst was commanded; record the steps and bursts so far (``job.on_progress``), so
    that a move a killed daemon leaves behind shows what it had commanded."""

    job: Job


@dataclass(frozen=True)
class Finished:
    """Event: the job is over; record the result and release the caller."""

    job: Job
    result: JobResult


@dataclass(frozen=True)
class SavePosition:
    """Event: persist the part's position (m; part 1's x) and every part's pose."""

    position_m: float
    poses: Reading = ()


@dataclass(frozen=True)
class Fault:
    """Event: a link is lost (``link``: ``amplifier`` or ``sensor``)."""

    link: str
    message: str


@dataclass(frozen=True, eq=False)
class Decide:
    """Event: ask the navigator for ``job``'s next burst from the measured ``reading``, off the
    tick (the pose planner takes milliseconds of a 10 ms period); the answer comes back as a
    :class:`Decision`.  ``refined``: the job's ``refined`` flag when asked (a decision may set
    it, and the policy puts it back when it measures again before the burst)."""

    job: Job
    reading: Reading
    refined: bool


@dataclass(frozen=True)
class Decision:
    """The navigator's answer to ``request``: the next burst, or (status, reason) when the job is over."""

    request: Decide
    answer: Burst | tuple[str, str]


Output = Command | Started | Progress | Finished | SavePosition | Fault | Decide
