"""The cyclic garbage collector, run in the tick's slack rather than wherever it triggers.

CPython collects reference cycles when allocations pass a threshold, in whichever thread is
allocating at that moment, and holds the interpreter for the whole collection. On the
daemon's heap a full collection took 22–42 ms (the console's burst of status requests set one
off about once a second), so the tick could not run for 2–4 periods. Collections of the young
generations took 0.2–3 ms; each one delayed a tick that woke during it by that much.

While a loop runs, the tick thread takes the collector over:

- the heap built before the start (modules, the configuration, the drivers) is frozen with
  :func:`gc.freeze`, so a full collection no longer traverses it;
- automatic collection is off;
- after each tick's work, the tick collects whatever generation CPython's own thresholds say
  is due (:func:`due_generation`).

A collection then starts at the beginning of a period's slack, not in front of a deadline.
The collector is process-wide. Loops share the take-over: the first loop that starts takes it,
and the last that stops hands it back (unfrozen, and enabled if it was).
"""

from __future__ import annotations

import gc
import logging
import threading
import time

log = logging.getLogger(__name__)

_lock = threading.Lock()
_holders = 0
_was_enabled = True


def due_generation(counts: tuple[int, int, int], thresholds: tuple[int, int, int]) -> int | None:
    """The generation CPython would collect now, if any (``gc.get_count()``, ``gc.get_threshold()``).

    Generation 0 is due when its allocations exceed its threshold; an older one when, in
    addition, the collections of the generation below it since its own last collection exceed
    its threshold; the oldest such generation is collected (CPython's ``gc_collect_generations``).
    CPython also holds a full collection back until the objects that reached the oldest
    generation since the last one are a quarter of it (a count Python cannot read); here a full
    collection runs when due, which after a freeze covers only what was made since the start.
    """
    if counts[0] <= thresholds[0]:
        return None
    for generation in (2, 1):
        if thresholds[generation] > 0 and counts[generation] > thresholds[generation]:
            return generation
    return 0


class TickCollector:
    """The collections one loop runs in its slack, and what they cost (s).

    active: False leaves the collector to CPython (every method does nothing).
    """

    def __init__(self, active: bool = True) -> None:
        self.active = active
        self.collections = 0
        self.longest_s = 0.0
        self._holding = False

    def take_over(self) -> None:
        """Freeze the heap and turn automatic collection off (the first loop to start does)."""
        global _holders, _was_enabled
        with _lock:
            if self._holding or not self.active:
                return
            if _holders == 0:
                _was_enabled = gc.isenabled()
                gc.freeze()
                gc.disable()
                log.debug("collector taken over: %d objects frozen", gc.get_freeze_count())
            _holders += 1
            self._holding = True

    def hand_back(self) -> None:
        """Unfreeze and restore automatic collection (the last loop to stop does)."""
        global _holders
        with _lock:
            if not self._holding:
                return
            self._holding = False
            _holders -= 1
            if _holders == 0:
                gc.unfreeze()
                if _was_enabled:
                    gc.enable()

    def collect_due(self) -> int | None:
        """Run the collection that is due, if any; the generation collected."""
        generation = due_generation(gc.get_count(), gc.get_threshold()) if self._holding else None
        if generation is not None:
            began = time.perf_counter()
            gc.collect(generation)
            took = time.perf_counter() - began
            self.collections += 1
            self.longest_s = max(self.longest_s, took)
        return generation
