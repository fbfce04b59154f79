"""The two clocks that drive the firmware's tick loop (DESIGN §6).

Both measure seconds since the loop started.  :class:`RealTimeClock` sleeps to
monotonic deadlines (``time.monotonic``), so ticks can be late; the loop
measures by how much.  :class:`VirtualClock` jumps straight to each deadline:
ticks are never late, the loop runs as fast as the CPU allows and every run
with the same inputs produces the same DAC stream (tests, sweeps).
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """What the tick loop needs from a clock."""

    realtime: bool

    def now_s(self) -> float:
        """Seconds since the clock started."""
        ...

    def sleep_until(self, deadline_s: float) -> float:
        """Wait until ``deadline_s`` (seconds since start); return the time on waking."""
        ...

    def work_s(self) -> float:
        """The calling thread's work so far, seconds: what the world's physics costs a tick."""
        ...


class RealTimeClock:
    """Wall time from ``time.monotonic``; ``sleep_until`` may wake late."""

    realtime = True

    def __init__(self) -> None:
        self._start = time.monotonic()

    def now_s(self) -> float:
        return time.monotonic() - self._start

    def sleep_until(self, deadline_s: float) -> float:
        remaining = deadline_s - self.now_s()
        if remaining > 0:
            time.sleep(remaining)
        return self.now_s()

    def work_s(self) -> float:
        """The thread's CPU time (time spent waiting for the CPU is not the world's)."""
        return time.thread_time()


class VirtualClock:
    """Simulated time: ``sleep_until`` returns at once, exactly on the deadline."""

    realtime = False

    def __init__(self) -> None:
        self._now = 0.0

    def now_s(self) -> float:
        return self._now

    def sleep_until(self, deadline_s: float) -> float:
        self._now = max(self._now, deadline_s)
        return self._now

    def work_s(self) -> float:
        """Simulated time: work costs none unless a subclass spends it."""
        return self._now
