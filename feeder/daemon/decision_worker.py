"""The navigator's decisions off the tick: one thread of their own, one decision at a time.

The pose planner weighs hundreds of candidate bursts per decision (2–30 ms of a
10 ms period): on the tick it would delay the next ticks, a STOP among them.
The policy emits a :class:`~feeder.daemon.jobs.Decide`; :class:`DecisionWorker`
runs it and hands the :class:`~feeder.daemon.jobs.Decision` to its callback,
which the loop acts on at once (waiting for the next tick would add a period per burst).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable

from feeder.daemon.jobs import Decide, Decision

log = logging.getLogger(__name__)


class DecisionWorker:
    """Runs ``decide`` for each submitted request, in order, on a thread of its own, and
    ``decided`` with each answer (on that thread).

    ``last_s`` and ``longest_s``: wall time of the last and the longest decision (s).
    """

    def __init__(self, decide: Callable[[Decide], Decision], decided: Callable[[Decision], None]) -> None:
        self._decide = decide
        self._decided = decided
        self._requests: queue.SimpleQueue[Decide | None] = queue.SimpleQueue()
        self.last_s = 0.0
        self.longest_s = 0.0
        self._thread = threading.Thread(target=self._run, name="decisions", daemon=True)
        self._thread.start()

    def submit(self, request: Decide) -> None:
        self._requests.put(request)

    def close(self) -> None:
        """Finish the decision in progress (if any) and end the thread."""
        self._requests.put(None)
        self._thread.join(timeout=5.0)

    def _run(self) -> None:
        while (request := self._requests.get()) is not None:
            began = time.perf_counter()
            try:
                decision = self._decide(request)
            except Exception as err:
                # the thread's one boundary: a navigator failing in an unforeseen way ends the
                # job with what went wrong (else it would wait for an answer for ever)
                log.exception("the navigator failed to decide")
                decision = Decision(request, ("fault", f"the navigator failed: {type(err).__name__}: {err}"))
            self.last_s = time.perf_counter() - began
            self.longest_s = max(self.longest_s, self.last_s)
            self._decided(decision)
