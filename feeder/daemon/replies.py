"""Typed replies of the daemon, as :class:`~feeder.daemon.client.Client` returns them.

Frozen dataclasses in SI units with the protocol's key names; each ``from_dict``
reads the daemon's reply object, and ``raw`` (where present) keeps that object as
it came, so fields added later are there.  A reply without the protocol's fields
raises ``KeyError``, ``TypeError`` or ``ValueError`` (the client reports it as
:class:`~feeder.errors.DaemonUnreachable`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from feeder.pose import Pose


@dataclass(frozen=True)
class LearnedStep:
    """The daemon's learned step for one ``mode/direction``: step and burst offset, m."""

    step_m: float
    std_m: float
    offset_m: float
    offset_std_m: float
    steps: int

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LearnedStep:
        return cls(
            float(d["step_m"]),
            float(d["std_m"]),
            float(d["offset_m"]),
            float(d["offset_std_m"]),
            int(d["steps"]),
        )


def _learned(d: dict[str, Any]) -> dict[str, LearnedStep]:
    """The one-axis steps; a pose planner's response (another shape) stays in ``raw``."""
    return {
        name: LearnedStep.from_dict(est)
        for name, est in d.items()
        if isinstance(est, dict) and "step_m" in est
    }


def _opt(value: Any) -> float | None:
    return None if value is None else float(value)


@dataclass(frozen=True)
class MoveResult:
    """How a move (``kind`` ``move``) or calibration (``calibrate``) ended.

    status: ``done``, ``stopped``, ``stalled``, ``limit``, ``oscillating``,
    ``unreachable``, ``fault`` or ``refused``; ``reason`` in words.  Positions in m,
    ``duration_s`` in s; ``estimates`` the learned steps after it; ``steps_estimated``:
    a burst was cut short and its steps estimated from time.  A pose move adds the
    ``part``, ``target_pose`` and reached ``pose`` ((x_m, y_m, psi_rad), plate frame),
    ``error_m`` (distance of the centre from the target) and ``error_rad`` (angle modulo
    the part's symmetry).  ``raw`` is the daemon's object as it came (fields added later
    are there).
    """

    kind: str
    status: str
    reason: str
    target_m: float | None
    start_m: float | None
    reached_m: float | None
    error_m: float | None
    steps: int
    bursts: int
    duration_s: float
    estimates: dict[str, LearnedStep]
    move_id: int | None
    steps_estimated: bool = False
    part: int | None = None
    target_pose: Pose | None = None
    pose: Pose | None = None
    error_rad: float | None = None
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    @property
    def done(self) -> bool:
        return self.status == "done"

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MoveResult:
        return cls(
            kind=str(d["kind"]),
            status=str(d["status"]),
            reason=str(d["reason"]),
            target_m=_opt(d["target_m"]),
            start_m=_opt(d.get("start_m")),
            reached_m=_opt(d["reached_m"]),
            error_m=_opt(d.get("error_m")),
            steps=int(d["steps"]),
            bursts=int(d["bursts"]),
            duration_s=float(d["duration_s"]),
            estimates=_learned(d.get("estimates") or {}),
            move_id=d.get("move_id"),
            steps_estimated=bool(d.get("steps_estimated", False)),
            part=d.get("part"),
            target_pose=_pose(d.get("target_pose")),
            pose=_pose(d.get("pose")),
            error_rad=_opt(d.get("error_rad")),
            raw=d,
        )


@dataclass(frozen=True)
class PartPose:
    """A part on the plate: its id, shape, size (m) and pose (None while unseen)."""

    id: int
    pose: Pose | None
    shape: str = "rectangle"
    size_m: tuple[float, ...] = ()

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PartPose:
        return cls(
            id=int(d["id"]),
            pose=_pose(d.get("pose")),
            shape=str(d.get("shape", "rectangle")),
            size_m=tuple(float(v) for v in d.get("size_m") or ()),
        )


@dataclass(frozen=True)
class Accepted:
    """A job the daemon accepted without waiting for it (``wait=False``).

    queue_position: 0 when it started at once, else its place in the queue.
    """

    queue_position: int


@dataclass(frozen=True)
class StopResult:
    """``stopped``: a move was running and was told to stop; ``dequeued``: queued jobs dropped."""

    stopped: bool
    dequeued: int


@dataclass(frozen=True)
class Status:
    """The daemon's state (``idle``, ``moving``, ``calibrating``, ``fault``, ...), m and s;
    ``loop_state`` the control policy's (``idle``, ``moving``, ``settling``, ``holding``,
    ``fault``) where the daemon reports it.

    ``parts`` every part's pose (a plate driven in x, y and θ; one part otherwise).
    ``camera_moves``: a camera calibration is moving the plate (``state`` stays ``idle``);
    ``camera_moves_progress`` what its moves are doing now ("y: offset 0 → 100 V in 0.05 V
    steps"), else None.
    ``raw`` holds the whole reply (timing, waveforms, transport, ...).
    """

    state: str
    position_m: float | None
    position_state: str
    last_known_position_m: float | None
    target_m: float | None
    fault: str | None
    queued_moves: int
    tolerance_m: float
    travel_limits_m: tuple[float, float]
    estimates: dict[str, LearnedStep]
    last_result: MoveResult | None
    loop_state: str | None = None
    parts: tuple[PartPose, ...] = ()
    camera_moves: bool = False
    camera_moves_progress: str | None = None
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Status:
        lo, hi = d["travel_limits_m"]
        last = d.get("last_result")
        return cls(
            state=str(d["state"]),
            position_m=_opt(d["position_m"]),
            position_state=str(d["position_state"]),
            last_known_position_m=_opt(d.get("last_known_position_m")),
            target_m=_opt(d.get("target_m")),
            fault=d.get("fault"),
            queued_moves=int(d.get("queued_moves", 0)),
            tolerance_m=float(d["tolerance_m"]),
            travel_limits_m=(float(lo), float(hi)),
            estimates=_learned(d.get("estimates") or {}),
            last_result=None if last is None else MoveResult.from_dict(last),
            loop_state=d.get("loop_state"),
            parts=tuple(PartPose.from_dict(p) for p in d.get("parts") or ()),
            camera_moves=d.get("camera_moves") is True,
            camera_moves_progress=d.get("camera_moves_progress"),
            raw=d,
        )


@dataclass(frozen=True)
class MoveRecord:
    """One recorded move from the history: times in s (Unix), positions in m."""

    id: int
    started_s: float
    finished_s: float | None
    start_m: float | None
    target_m: float
    reached_m: float | None
    error_m: float | None
    steps: int
    bursts: int
    status: str
    reason: str
    step_forward_m: float | None
    step_backward_m: float | None
    steps_estimated: bool = False
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MoveRecord:
        return cls(
            id=int(d["id"]),
            started_s=float(d["started_s"]),
            finished_s=_opt(d["finished_s"]),
            start_m=_opt(d["start_m"]),
            target_m=float(d["target_m"]),
            reached_m=_opt(d["reached_m"]),
            error_m=_opt(d["error_m"]),
            steps=int(d["steps"]),
            bursts=int(d["bursts"]),
            status=str(d["status"]),
            reason=str(d["reason"]),
            step_forward_m=_opt(d.get("step_forward_m")),
            step_backward_m=_opt(d.get("step_backward_m")),
            steps_estimated=bool(d.get("steps_estimated", False)),
            raw=d,
        )


def _pose(value: Any) -> Pose | None:
    """A reply's [x, y, angle] (angle None: any angle, as NaN)."""
    if value is None:
        return None
    x, y, psi = value
    return (float(x), float(y), math.nan if psi is None else float(psi))
