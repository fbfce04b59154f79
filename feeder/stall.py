"""Whether this process stood still: SIGSTOP, a suspended virtual machine, heavy swapping.

Timeouts measure the other side's silence on the monotonic clock, which runs on while the
process does not: after a 2.5 s SIGSTOP the daemon declared its camera ("no poses within 2 s")
and its CANopen nodes ("no heartbeat for 2644 ms") lost, though their frames were waiting in
its buffers.  A monitor thread that should wake every :data:`PERIOD_S` records the gaps when
it did not; :func:`stalled_since` tells a timeout how much of its window was such a gap, so
that the silence is judged again over a window of its own.
"""

from __future__ import annotations

import collections
import threading
import time

PERIOD_S = 0.05
"""The monitor's wake-up period (s)."""
GAP_S = 0.25
"""A wake-up this much later than due (s) is a stall (a loaded 2-core machine wakes within ~10 ms)."""
KEPT = 64
"""The most recent stalls kept."""

_stalls: collections.deque[tuple[float, float]] = collections.deque(maxlen=KEPT)
_lock = threading.Lock()
_thread: threading.Thread | None = None
_due: float | None = None  # when the monitor should wake next


def _watch() -> None:
    global _due
    _due = time.monotonic() + PERIOD_S
    while True:
        time.sleep(max(_due - time.monotonic(), 0.0))
        now = time.monotonic()
        with _lock:
            if now - _due > GAP_S:
                _stalls.append((_due, now))
            _due = now + PERIOD_S


def watch() -> None:
    """Start the monitor (once per process; later calls do nothing)."""
    global _thread
    with _lock:
        if _thread is None:
            _thread = threading.Thread(target=_watch, name="stall-monitor", daemon=True)
            _thread.start()


def why_late(late_s: float, cpu_s: float) -> str:
    """Why a thread woke ``late_s`` (s) late, the process having used ``cpu_s`` (s) of CPU
    (``time.process_time()``, every thread) meanwhile: busy itself, or stopped or starved."""
    if cpu_s >= 0.5 * late_s:
        return f"this process kept the interpreter busy ({cpu_s:.2f} s of CPU: start-up, a long computation?)"
    return "the process stood still or got no CPU (SIGSTOP, a suspended machine, swapping, a loaded host?)"


def stalled_since(start_s: float) -> float:
    """How long (s) the process stood still after ``start_s`` (``time.monotonic()``), as far as
    the monitor saw (0 before :func:`watch`): the stalls it recorded, and one it has not woken
    from yet (a caller that resumed first: threads resume in any order)."""
    now = time.monotonic()
    with _lock:
        stalled = sum(end - max(begin, start_s) for begin, end in _stalls if end > start_s)
        if _due is not None and now - _due > GAP_S:
            stalled += now - max(_due, start_s)
        return stalled
