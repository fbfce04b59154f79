"""Per-source pacing of console password tries (login throttle), shared by every connection.

Intervals in seconds, on ``time.monotonic()``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

MIN_LOGIN_INTERVAL_S = 0.2
"""Password tries from one source are evaluated at least this far apart (≤ 5 tries/s) ..."""
MAX_LOGIN_INTERVAL_S = 1.0
"""... and the spacing doubles with every failed try, up to this."""
FORGET_FAILURES_S = 60.0
"""A source with no try for this long starts afresh."""


@dataclass
class _Source:
    failures: int = 0  # consecutive failed tries
    next_free_s: float = 0.0  # monotonic time the next try may be evaluated
    last_s: float = 0.0  # monotonic time of the last try


class LoginThrottle:
    """Paces password tries per source (the peer's address, or ``pty``), across connections.

    Each try reserves the source's next slot: tries are evaluated in arrival
    order, at least ``MIN_LOGIN_INTERVAL_S`` apart, and the spacing doubles
    with each consecutive failure up to ``MAX_LOGIN_INTERVAL_S``; a correct
    password resets it.  Reconnecting does not help: the state is per source,
    not per connection.  :meth:`attempt` sleeps in the caller's thread (each
    connection has its own), so one source's penalty never delays another
    session or the firmware's tick.
    """

    def __init__(
        self,
        min_interval_s: float = MIN_LOGIN_INTERVAL_S,
        max_interval_s: float = MAX_LOGIN_INTERVAL_S,
        forget_s: float = FORGET_FAILURES_S,
    ) -> None:
        self.min_interval_s = min_interval_s
        self.max_interval_s = max_interval_s
        self.forget_s = forget_s
        self._lock = threading.Lock()
        self._sources: dict[str, _Source] = {}

    def interval_s(self, failures: int) -> float:
        """Spacing of tries after ``failures`` consecutive failed ones, s."""
        return min(self.min_interval_s * 2.0 ** min(failures, 32), self.max_interval_s)

    def attempt(self, source: str, check: Callable[[], bool]) -> bool:
        """Wait for ``source``'s next slot, then run ``check`` (is the password right?)."""
        delay = self._reserve(source) - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        ok = check()
        with self._lock:
            state = self._sources.setdefault(source, _Source())
            now = time.monotonic()
            if ok:
                state.failures = 0
            else:
                state.failures += 1
                state.next_free_s = max(state.next_free_s, now + self.interval_s(state.failures))
        return ok

    def _reserve(self, source: str) -> float:
        with self._lock:
            now = time.monotonic()
            self._forget(now)
            state = self._sources.setdefault(source, _Source())
            at = max(now, state.next_free_s)
            state.next_free_s = at + self.interval_s(state.failures)
            state.last_s = at
            return at

    def _forget(self, now: float) -> None:
        stale = [
            s
            for s, state in self._sources.items()
            if now - max(state.last_s, state.next_free_s) > self.forget_s
        ]
        for source in stale:
            del self._sources[source]
