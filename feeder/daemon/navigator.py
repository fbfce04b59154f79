"""What the policy asks of a navigator: where a job steps next (:class:`Navigator`).

:class:`~feeder.daemon.line_navigator.LineNavigator` steps along one axis,
:class:`~feeder.daemon.pose_navigator.PoseNavigator` in x, y and θ; the policy
(:mod:`feeder.daemon.policy`) only measures, steps, stops and records.
"""

from __future__ import annotations

from typing import Any, Protocol

from feeder.daemon.jobs import Burst, Job, Reading
from feeder.daemon.step_estimator import StepEstimate
from feeder.pose import Pose


class Navigator(Protocol):
    """Decides where a job steps next (see :class:`~feeder.daemon.line_navigator.LineNavigator`)."""

    axes: tuple[str, ...]

    def prepare(self, job: Job, reading: Reading | None) -> str | None:
        """Resolve ``job``'s target against ``reading`` (the parts where the move starts); the
        reason it is refused, or None."""
        ...

    def outside(self, reading: Reading) -> str | None:
        """Why ``reading`` shows a part where the running move (the one :meth:`prepare` last
        accepted) must stop, out of the travel; None."""
        ...

    def settled(self, recent: list[Reading]) -> bool: ...

    def learn(self, burst: Burst, learnable: bool, before: Reading, after: Reading) -> bool: ...

    def expects_motion(self, burst: Burst, reading: Reading) -> bool: ...

    def next_burst(self, job: Job, reading: Reading) -> Burst | tuple[str, str]: ...

    def reached(self, job: Job, reading: Reading) -> None: ...

    def release(self, part: int | None = None) -> list[int]: ...

    def holds(self) -> list[dict[str, Any]]: ...

    def estimates(self) -> dict[str, StepEstimate]: ...

    def estimates_json(self) -> dict[str, Any]: ...


def not_on_plate(part: int, reading: Reading) -> str | None:
    """Why ``part`` cannot be addressed (the camera sees fewer parts), or None."""
    if 1 <= part <= len(reading):
        return None
    return f"part {part} is not on the plate (the camera sees {len(reading)} part(s))"


def part_pose(job: Job, reading: Reading) -> Pose:
    """The job's part in ``reading`` (the last one seen if the camera sees fewer parts)."""
    return reading[min(job.part, len(reading)) - 1]
