"""The daemon's request threads stand back while the tick is due.

Python runs one thread at a time (the GIL). A tick that wakes while another thread runs
Python waits until that thread hands the interpreter over: up to a switch interval (0.5 ms)
per thread already queued for it, and longer when the operating system has preempted the
holder. During the console's burst of 100 concurrent status requests the console's threads
held it most of the time, and the tick's p99 lateness was 1.7–5.9 ms against its 0.5 ms goal.

So the threads that serve requests yield to the tick, as a lower-priority task yields to a
real-time one on a controller. The tick announces each deadline (:meth:`QuietWindow.due`)
and says when its work is done (:meth:`QuietWindow.served`). From ``guard_s`` before the
deadline until then, a request thread that reaches a checkpoint (:meth:`QuietWindow.hold`:
an event loop made by :func:`quiet_event_loop`, as the console's is, before each callback;
the daemon's request handler at entry) waits with the interpreter released. The tick then
finds the interpreter free when it wakes. A thread waits at most until ``max_hold_s`` after
the deadline, so a tick that stalls cannot stall the console.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

QUIET_BEFORE_TICK_S = 2e-3
"""How long before a deadline request threads stand back. A callback of the console's event
loop that starts just before the window opens runs on into it; the window must outlast it.
Measured on the console's burst: 1 ms left p99 lateness at 0.7–2.8 ms, 2 ms brought it
within 0.5 ms (docs/console.md)."""
MAX_SHARE = 0.25
"""At most this share of a period is quiet: a fast loop (up to 1 kHz) still leaves its request
threads most of each period."""
MAX_HOLD_S = 3e-3
"""The longest a request thread waits past a deadline for the tick to finish its work."""

log = logging.getLogger(__name__)


def guard_for(period_s: float) -> float:
    """How long before each deadline a loop of this period (s) keeps its request threads quiet."""
    return min(QUIET_BEFORE_TICK_S, MAX_SHARE * period_s)


class QuietWindow:
    """The window, from ``guard_s`` before a tick's deadline until its work is done, in which
    request threads do not run Python; clock: the tick's (s, monotonic)."""

    def __init__(
        self,
        guard_s: float = QUIET_BEFORE_TICK_S,
        max_hold_s: float = MAX_HOLD_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.guard_s = guard_s
        self.max_hold_s = max_hold_s
        self._clock = clock
        self._deadline = math.inf
        self._served = threading.Event()
        self._served.set()
        self.holds = 0
        """How many times a request thread stood back for the tick (a statistic: threads count
        it without a lock)."""

    def due(self, deadline: float) -> None:
        """The tick, before it sleeps: its next deadline (s, on ``clock``)."""
        self._served.clear()
        self._deadline = deadline

    def served(self) -> None:
        """The tick, after its work: request threads may run until the next window."""
        self._deadline = math.inf
        self._served.set()

    def hold(self) -> None:
        """A request thread's checkpoint: returns at once outside the window; inside it, waits
        (interpreter released) until the tick is served, at most ``max_hold_s`` past the deadline."""
        deadline = self._deadline
        now = self._clock()
        if now < deadline - self.guard_s or self._served.is_set():
            return
        self.holds += 1
        self._served.wait(max(0.0, deadline + self.max_hold_s - now))


class _QuietReady(collections.deque[Callable[..., Any]]):
    """asyncio's queue of ready callbacks (``loop._ready``), taken one by one by the loop: each
    waits at the tick's quiet window before it runs (:meth:`QuietWindow.hold`)."""

    def __init__(self, quiet: QuietWindow) -> None:
        super().__init__()
        self._quiet = quiet

    def popleft(self) -> Callable[..., Any]:
        self._quiet.hold()
        return super().popleft()


def quiet_event_loop(quiet: QuietWindow) -> asyncio.AbstractEventLoop:
    """A new asyncio event loop that runs no callback while ``quiet`` is open.

    asyncio runs every callback (a request's next step, a socket's data) by taking it from
    the loop's ready queue; this loop's queue holds each one at the window first. The queue is
    asyncio's own attribute (CPython's selector loop): where it is missing, the loop runs
    unchecked and says so.
    """
    loop = asyncio.new_event_loop()
    ready = getattr(loop, "_ready", None)
    if isinstance(ready, collections.deque) and not ready:
        loop._ready = _QuietReady(quiet)  # type: ignore[attr-defined]
    else:
        log.warning("this event loop has no ready queue to hold: it runs during the tick")
    return loop
