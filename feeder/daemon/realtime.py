"""Real-time scheduling of the daemon: the tick first, the daemon's other threads next, then
every other process (Linux ``SCHED_FIFO`` where the process may raise it: root,
``CAP_SYS_NICE`` or an ``rtprio`` limit; ordinary scheduling elsewhere, same code).

Python runs one thread at a time (the interpreter lock), which defeats priorities by itself:
a tick that wakes waits for whichever thread holds the lock.  Two measures bound that wait
(docs/console.md has the measurements):

- every thread of the daemon runs at :data:`SERVICE_PRIORITY`, below the tick and above every
  ordinary process, so no outside process (a browser, a script firing requests, the
  simulator) preempts a thread while it holds the lock and the tick waits;
- the tick sleeps in a small C helper (``_tick_wake``, built with the package; without it, in
  :func:`time.sleep`) that sets the switch interval to :data:`URGENT_SWITCH_INTERVAL_S` as it
  asks for the lock back: each holder then hands it over within tens of µs, not a whole
  :data:`TICK_SWITCH_INTERVAL_S`.

Raised threads reset on fork: no program the daemon starts inherits real-time priority.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections.abc import Callable

try:
    from feeder.daemon import _tick_wake  # type: ignore[attr-defined]
except ImportError:  # built without a C compiler: the tick sleeps in Python
    _tick_wake = None

log = logging.getLogger(__name__)

TICK_PRIORITY = 10
"""The tick thread's SCHED_FIFO priority: it wakes before every other thread on the machine; a
tick sleeps 99 % of its period, so it never starves them."""
SERVICE_PRIORITY = 5
"""Every other thread of the daemon (amplifier and record workers, sensor feed, decisions,
cameras, socket and console servers)."""
TICK_SWITCH_INTERVAL_S = 0.5e-3
"""The interpreter's switch interval while a loop runs (Python's default is 5 ms)."""
URGENT_SWITCH_INTERVAL_S = 20e-6
"""The switch interval while the woken tick waits for the interpreter (restored once it holds it)."""


def raise_thread(priority: int) -> str:
    """Make the calling thread SCHED_FIFO at ``priority`` if allowed; its policy's name
    (``fifo`` or ``other``)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
    except OSError as err:  # PermissionError without the right to raise it
        log.debug("thread %s stays at ordinary priority: %s", threading.current_thread().name, err)
        return "other"
    return "fifo"


def raise_tick() -> str:
    """The tick's thread: :data:`TICK_PRIORITY`, and the interpreter handing over every
    :data:`TICK_SWITCH_INTERVAL_S`; the thread's policy's name."""
    sys.setswitchinterval(min(sys.getswitchinterval(), TICK_SWITCH_INTERVAL_S))
    policy = raise_thread(TICK_PRIORITY)
    if policy != "fifo":
        log.info("the tick runs at ordinary priority (SCHED_FIFO refused)")
    return policy


def raise_daemon_threads() -> int:
    """Every live thread but the main one (a host program's) and those already real-time to
    :data:`SERVICE_PRIORITY`; how many were raised (0 where not allowed)."""
    main = threading.main_thread()
    raised = 0
    for thread in threading.enumerate():
        tid = thread.native_id
        if thread is main or tid is None or not thread.is_alive():
            continue
        try:
            if os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO:
                continue
            policy = os.SCHED_FIFO | os.SCHED_RESET_ON_FORK
            os.sched_setscheduler(tid, policy, os.sched_param(SERVICE_PRIORITY))
        except ProcessLookupError:  # ended meanwhile
            continue
        except PermissionError:
            return raised
        raised += 1
    return raised


def sleep_until(deadline_s: float, clock: Callable[[], float] = time.monotonic) -> None:
    """Sleep until ``clock()`` reaches ``deadline_s``; with the C helper and the monotonic clock,
    take the interpreter back with the urgent switch interval."""
    if _tick_wake is not None and clock is time.monotonic:
        _tick_wake.sleep_until(deadline_s, URGENT_SWITCH_INTERVAL_S)
        return
    delay = deadline_s - clock()
    if delay > 0:
        time.sleep(delay)
