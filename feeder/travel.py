"""Where parts' centres may go on the plate: the travel, a rectangle in the plate frame (m).

The camera must keep seeing every part (docs/pose-control.md, *travel*): bursts are cut before
a part leaves the travel, and a part already outside it (put there by hand, or carried there)
may stay as far out but go no further (:meth:`Travel.keeps`).
"""

from __future__ import annotations

from dataclasses import dataclass

from feeder.pose import Pose


@dataclass(frozen=True)
class Travel:
    """Where a part's centre may go, plate frame: (lo, hi) in x and in y (m)."""

    x_m: tuple[float, float]
    y_m: tuple[float, float]

    def contains(self, x_m: float, y_m: float, margin_m: float = 0.0) -> bool:
        return (
            self.x_m[0] + margin_m <= x_m <= self.x_m[1] - margin_m
            and self.y_m[0] + margin_m <= y_m <= self.y_m[1] - margin_m
        )

    def beyond(self, x_m: float, y_m: float) -> tuple[float, float]:
        """How far (m) the point lies outside the travel in x and in y (0 within)."""
        return (
            max(self.x_m[0] - x_m, x_m - self.x_m[1], 0.0),
            max(self.y_m[0] - y_m, y_m - self.y_m[1], 0.0),
        )

    def keeps(self, start: Pose, end: Pose, slack_m: float = 0.0) -> bool:
        """A part going from ``start`` to ``end`` stays within the travel, or (having started
        outside it) no further outside than it started, in x and in y, give or take ``slack_m``
        (m: a reading's noise, and the plate's rest moving when an axis is enabled, its waveform
        changed or grounded: a part left 0.2 µm inside the edge by a move, grounded, read 0.3 µm
        beyond it once the next move enabled x, and every move ended "limit" at 0 steps)."""
        was = self.beyond(start[0], start[1])
        now = self.beyond(end[0], end[1])
        return all(n <= w + slack_m for n, w in zip(now, was, strict=True))

    def describe(self) -> str:
        """The travel as a refusal names it: "x (lo, hi) m, y (lo, hi) m"."""
        return f"x {self.x_m} m, y {self.y_m} m"

    def json(self) -> dict[str, list[float]]:
        return {"x": list(self.x_m), "y": list(self.y_m)}
