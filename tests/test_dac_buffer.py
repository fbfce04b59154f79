"""The axis' DAC buffer (firmware_sim/dac_buffer.py) against plain concatenated arrays."""

from __future__ import annotations

import numpy as np

from firmware_sim.dac_buffer import MIN_CAPACITY, DacBuffer


def test_appends_takes_and_keeps_match_concatenated_arrays() -> None:
    """Random ticks (append or hold, take), commands (keep) and a burst of appends past the capacity:
    the buffer holds what concatenating and slicing the arrays would, and what it handed out
    is unchanged by later appends and compactions."""
    rng = np.random.default_rng(3)
    buffer = DacBuffer()
    codes = np.zeros(0, dtype=np.int64)
    steps = np.zeros(0, dtype=np.int64)
    phases = np.zeros(0, dtype=np.uint64)
    taken: list[tuple[np.ndarray, np.ndarray]] = []  # (a copy, the view handed out)
    compacted = 0
    for _ in range(3000):
        n = int(rng.integers(1, 5 * MIN_CAPACITY if rng.random() < 0.01 else 300))
        new = (
            rng.integers(0, 1 << 20, n),
            rng.integers(-1, 2, n),
            rng.integers(0, 1 << 60, n, dtype=np.uint64),
        )
        before = buffer._codes
        if rng.random() < 0.3:  # an axis at rest: one code and phase
            new = (np.full(n, new[0][0]), np.zeros(n, dtype=np.int64), np.full(n, new[2][0]))
            buffer.hold(n, int(new[0][0]), int(new[2][0]))
        else:
            buffer.append(*new)
        compacted += buffer._codes is not before
        codes, steps, phases = (
            np.concatenate(pair) for pair in zip((codes, steps, phases), new, strict=True)
        )
        if rng.random() < 0.1:
            kept = int(rng.integers(0, len(codes) + 1))
            buffer.keep(kept)
            codes, steps, phases = codes[:kept], steps[:kept], phases[:kept]
        n = int(rng.integers(0, len(codes) + 1))
        got = buffer.take(n)
        taken.append((got[0].copy(), got[0]))
        assert np.array_equal(got[0], codes[:n]) and np.array_equal(got[1], steps[:n])
        codes, steps, phases = codes[n:], steps[n:], phases[n:]
        assert len(buffer) == len(codes)
        assert np.array_equal(buffer.codes, codes) and np.array_equal(buffer.steps, steps)
        assert np.array_equal(buffer.phases, phases) and buffer.phases.dtype == np.uint64
    assert compacted > 10
    # the views handed out still read what was taken, after every later append and compaction
    assert all(np.array_equal(copy, view) for copy, view in taken)


def test_the_arrays_stay_within_twice_what_they_hold() -> None:
    buffer = DacBuffer()
    for _ in range(1000):  # a tick: 100 samples in and out of 10 000 held
        buffer.append(
            np.zeros(100, dtype=np.int64), np.zeros(100, dtype=np.int64), np.zeros(100, dtype=np.uint64)
        )
        if len(buffer) > 10_000:
            buffer.take(100)
    assert len(buffer._codes) <= 2 * (10_000 + 100)
