"""The tick's timing: its scheduling priority and the statistics of its lateness.

:func:`raise_tick_priority` makes the tick thread of the
:class:`~feeder.daemon.control_loop.ControlLoop` real-time where the process may, and has the
interpreter hand over often; :class:`TickLateness` keeps the last ticks' lateness (wake-up −
deadline) and :func:`percentile_of_sorted` gives the jitter figures a status reports.
"""

from __future__ import annotations

import logging
import math
import os
import sys

import numpy as np

log = logging.getLogger(__name__)

TICK_PRIORITY = 10
"""The tick thread's SCHED_FIFO priority where the process may raise it (CAP_SYS_NICE, or an
rtprio limit): it then wakes before every ordinary thread on the machine (console clients,
the simulator, other users); a tick sleeps 99 % of its period, so it never starves them."""


TICK_SWITCH_INTERVAL_S = 0.5e-3
"""The interpreter's switch interval while a loop runs (``sys.setswitchinterval``; Python's
default is 5 ms): the longest a tick that wakes waits for a thread holding the interpreter (the
console's HTTP server, the camera's locating)."""


def raise_tick_priority() -> str:
    """Make the calling thread real-time (:data:`TICK_PRIORITY`) if allowed, and the interpreter
    hand over every :data:`TICK_SWITCH_INTERVAL_S`; the thread's policy's name."""
    sys.setswitchinterval(min(sys.getswitchinterval(), TICK_SWITCH_INTERVAL_S))
    try:
        # reset on fork: the threads it starts (the fault handler, a reconnect) and the programs
        # they start (firmware_sim again) run at ordinary priority
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(TICK_PRIORITY))
    except OSError as err:  # PermissionError without the right to raise it
        log.info("the tick runs at ordinary priority (SCHED_FIFO refused: %s)", err.strerror or err)
        return "other"
    return "fifo"


class TickLateness:
    """The last ``size`` ticks' lateness (wake-up − deadline, s) in a ring: a tick stores one
    float; a status copies the ring and sorts it, which numpy does without holding the
    interpreter (a deque converted to an array held it for ~0.3 ms per status, and the
    console asks 30 times a second)."""

    def __init__(self, size: int) -> None:
        self._ring = np.zeros(size)
        self.count = 0
        """Ticks recorded since the start."""

    def append(self, seconds: float) -> None:
        self._ring[self.count % self._ring.size] = seconds
        self.count += 1

    def last(self, n: int) -> np.ndarray:
        """The last ``n`` ticks' lateness (s), oldest first (fewer when fewer are kept)."""
        n = max(0, min(n, self.count, self._ring.size))
        return self._ring[np.arange(self.count - n, self.count) % self._ring.size]


def percentile_of_sorted(values: np.ndarray, q: float) -> float:
    """``np.percentile(values, q)`` (linear) of an already sorted, non-empty array."""
    rank = q / 100 * (values.size - 1)
    low = math.floor(rank)
    high = min(low + 1, values.size - 1)
    return float(values[low] + (rank - low) * (values[high] - values[low]))
