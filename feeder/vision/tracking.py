"""Parts across frames: stable identities by nearest-neighbour assignment.

Each frame's detections are matched to the tracks of the frame before by
``scipy.optimize.linear_sum_assignment`` on the centre distance (pixels); a
pair further apart than ``max_jump_px`` is no match.  An unmatched detection
starts a new track (a new id, never reused); a track unseen for more than
``max_missed`` frames ends.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from feeder.vision.model import Detection


@dataclass(frozen=True)
class Track:
    """A part followed over frames: its id, its latest detection, frames since it was last seen."""

    track_id: int
    detection: Detection
    missed: int = 0


class Tracker:
    """Keeps part identities from frame to frame (see the module doc)."""

    def __init__(self, max_jump_px: float = 50.0, max_missed: int = 5) -> None:
        self.max_jump_px = max_jump_px
        self.max_missed = max_missed
        self._tracks: list[Track] = []
        self._next_id = 1

    @property
    def tracks(self) -> tuple[Track, ...]:
        return tuple(self._tracks)

    def update(self, detections: tuple[Detection, ...] | list[Detection]) -> list[Track]:
        """Match one frame's detections; returns the tracks seen in this frame, in detection order."""
        matched: dict[int, int] = {}
        if self._tracks and detections:
            old = np.array([[t.detection.x_px, t.detection.y_px] for t in self._tracks])
            new = np.array([[d.x_px, d.y_px] for d in detections])
            cost = np.hypot(old[:, None, 0] - new[None, :, 0], old[:, None, 1] - new[None, :, 1])
            rows, cols = linear_sum_assignment(cost)
            matched = {
                int(c): int(r) for r, c in zip(rows, cols, strict=True) if cost[r, c] <= self.max_jump_px
            }
        seen: list[Track] = []
        kept: list[Track] = []
        for j, detection in enumerate(detections):
            if j in matched:
                track = Track(self._tracks[matched[j]].track_id, detection)
            else:
                track = Track(self._next_id, detection)
                self._next_id += 1
            seen.append(track)
        used = set(matched.values())
        for i, track in enumerate(self._tracks):
            if i not in used and track.missed < self.max_missed:
                kept.append(Track(track.track_id, track.detection, track.missed + 1))
        self._tracks = seen + kept
        return seen
