"""An axis' DAC buffer: the samples generated and not yet played, as a firmware keeps them in a
ring.  Each tick appends ~0.1 k samples and takes as many from the front of ~10 k held
(100 ms at 100 kS/s); the arrays grow to twice what they hold and are compacted only when full,
so a tick costs what it adds, not what the buffer holds (concatenating the held arrays three
times a tick per axis was ~15 µs of each axis' idle tick).  An axis at rest writes its code and
phase into the ring as they are (:meth:`DacBuffer.hold`), with no arrays made for them.
"""

from __future__ import annotations

import numpy as np

MIN_CAPACITY = 1024
"""Samples the arrays hold at least."""


class DacBuffer:
    """Parallel arrays of the pending samples: DAC codes, signed step marks (±1 where a period
    completes) and DDS phases.  The views it hands out stay valid: a compaction writes new
    arrays, and appends only write past the samples held."""

    def __init__(self) -> None:
        self._codes = np.zeros(MIN_CAPACITY, dtype=np.int64)
        self._steps = np.zeros(MIN_CAPACITY, dtype=np.int64)
        self._phases = np.zeros(MIN_CAPACITY, dtype=np.uint64)
        self._start = 0
        self._end = 0

    def __len__(self) -> int:
        return self._end - self._start

    @property
    def codes(self) -> np.ndarray:
        return self._codes[self._start : self._end]

    @property
    def steps(self) -> np.ndarray:
        return self._steps[self._start : self._end]

    @property
    def phases(self) -> np.ndarray:
        return self._phases[self._start : self._end]

    def append(self, codes: np.ndarray, steps: np.ndarray, phases: np.ndarray) -> None:
        """Add samples at the end (the three arrays of equal length)."""
        self._write(len(codes), codes, steps, phases)

    def hold(self, n: int, code: int, phase: int) -> None:
        """Add ``n`` samples of one code and DDS phase, no step marks (an axis at rest)."""
        self._write(n, code, 0, phase)

    def _write(
        self, n: int, codes: np.ndarray | int, steps: np.ndarray | int, phases: np.ndarray | int
    ) -> None:
        if self._end + n > len(self._codes):
            self._compact(len(self) + n)
        end = self._end + n
        self._codes[self._end : end] = codes
        self._steps[self._end : end] = steps
        self._phases[self._end : end] = phases
        self._end = end

    def take(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The first ``n`` samples' codes and step marks, which leave the buffer."""
        first, self._start = self._start, self._start + n
        return self._codes[first : self._start], self._steps[first : self._start]

    def keep(self, n: int) -> None:
        """Drop all but the first ``n`` samples (a command regenerates the rest)."""
        self._end = self._start + n

    def _compact(self, needed: int) -> None:
        """New arrays of twice ``needed`` with the held samples at their front."""
        capacity = max(MIN_CAPACITY, 2 * needed)
        held = slice(self._start, self._end)
        self._codes = _moved(self._codes[held], capacity)
        self._steps = _moved(self._steps[held], capacity)
        self._phases = _moved(self._phases[held], capacity)
        self._end -= self._start
        self._start = 0


def _moved(held: np.ndarray, capacity: int) -> np.ndarray:
    array = np.zeros(capacity, dtype=held.dtype)
    array[: len(held)] = held
    return array
