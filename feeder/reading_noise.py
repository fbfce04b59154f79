"""One reading's noise (σ of a coordinate) from readings of parts at rest, robust to their moves.

The median of the changes from one reading to the next, or of the changes of those changes,
whichever is smaller (white noise: 0.674 √2 σ and 0.674 √6 σ).  A step in the readings (a
lagging camera, a part nudged) changes one change, which the median ignores; a steady drift (a
creeping stack, a ramp) changes every change, but none of their changes.  Used by the camera
calibration's wait for a steady image (:mod:`feeder.vision.offset_moves`) and by the daemon,
which measures its sensor's noise while nothing moves the parts (:class:`RestingNoise`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

import numpy as np

MIN_CHANGES = 100
""":class:`RestingNoise` states σ from this many changes (and changes of changes) on."""
KEPT_CHANGES = 2000
"""... and from the last this many of each, ..."""
RENEW_EVERY = 10
"""... renewed every this many readings."""


def noise_from_changes(first: np.ndarray, second: np.ndarray) -> float:
    """σ from the changes ``first`` between consecutive readings and the changes ``second`` of
    those (any shape, the same unit)."""
    return float(
        min(
            np.median(np.abs(first)) / (0.6745 * math.sqrt(2)),
            np.median(np.abs(second)) / (0.6745 * math.sqrt(6)),
        )
    )


def reading_noise(points: np.ndarray) -> float:
    """σ of one coordinate from consecutive readings ``points`` (readings, parts, 2)."""
    return noise_from_changes(np.diff(points, axis=0), np.diff(points, n=2, axis=0))


class RestingNoise:
    """σ (m) of a coordinate of the parts' readings taken while nothing moved them (:meth:`add`;
    :meth:`restart` when something may move them, so that no change spans a move).

    :attr:`sigma_m` (None before :data:`MIN_CHANGES` changes at rest) is a plain attribute,
    renewed every :data:`RENEW_EVERY` readings by the thread that adds them: another thread may
    read it at any time."""

    def __init__(self) -> None:
        self.sigma_m: float | None = None
        self._first: deque[float] = deque(maxlen=KEPT_CHANGES)
        self._second: deque[float] = deque(maxlen=KEPT_CHANGES)
        self._last: np.ndarray | None = None
        self._last_change: np.ndarray | None = None
        self._added = 0

    def add(self, coordinates: Sequence[float]) -> None:
        """A reading of the parts at rest: every coordinate the sensor measures (m; x and y of
        each part, or a one-axis sensor's position)."""
        now = np.array(coordinates, dtype=float)
        if self._last is not None and self._last.shape == now.shape:
            change = now - self._last
            self._first.extend(change)
            if self._last_change is not None:
                self._second.extend(change - self._last_change)
            self._last_change = change
        else:
            self._last_change = None
        self._last = now
        self._added += 1
        if self._added % RENEW_EVERY == 0 and len(self._second) >= MIN_CHANGES:
            self.sigma_m = noise_from_changes(np.array(self._first), np.array(self._second))

    def restart(self) -> None:
        """Something may move the parts: the next reading starts a new run."""
        self._last = self._last_change = None
