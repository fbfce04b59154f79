"""What the pose planner decides next (docs/pose-control.md): a burst of steps of one axis, or the end.

Pure data, and the reason an x, y or θ burst cut by the travel gives
(:meth:`~feeder.travel.Travel.keeps`); no I/O.  Lengths in m, angles in rad.
"""

from __future__ import annotations

from dataclasses import dataclass

from feeder.pose import Pose
from feeder.travel import Travel

MAX_BURST_STEPS = 2000


@dataclass(frozen=True)
class AxisBurst:
    """``steps`` steps of ``axis`` in ``direction`` (+1/−1) with the waveform ``mode`` (coarse|fine;
    θ also anchor|anchor-fine, :data:`~feeder.pose_response.ANCHOR_MODES`)."""

    axis: str
    direction: int
    steps: int
    mode: str
    path: bool = False
    """A leg of a planned path (a pair's way to an anchor and back, A kept at an anchor that
    moves as B orbits): its reversals are the path's, not the loop's oscillation."""


@dataclass(frozen=True)
class Finish:
    """The move is over: status "done" (every target within tolerance) or "unreachable" with the reason."""

    status: str
    reason: str


def carry_refusal(travel: Travel, moving: str, k: int, pose: Pose) -> str:
    """Why ``moving`` ("moving part 1 further in +x") cannot be: it would carry part ``k``
    (index), at ``pose``, out of the travel, or further out when it already lies outside."""
    further = "further " if any(travel.beyond(pose[0], pose[1])) else ""
    return (
        f"{moving} would carry part {k + 1} at ({pose[0]:.4g}, {pose[1]:.4g}) m {further}out of the "
        f"travel {travel.describe()}: the camera must keep seeing it"
    )
