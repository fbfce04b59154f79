"""The sensor's reader thread, and the plausibility check of what it reads.

:class:`SensorFeed` reads the position sensor on a thread of its own, so a slow frame never
stalls the tick of the :class:`~feeder.daemon.control_loop.ControlLoop`, which takes what
arrived since its last one.  A reading :func:`implausible` (non-finite, off any plate) ends
the feed as a lost sensor; a silence that was the process's own standstill
(:mod:`feeder.stall`) does not.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable

from feeder import stall
from feeder.drivers.sensor import PositionSample, PositionSensor, SensorLost

log = logging.getLogger(__name__)

PLAUSIBLE_M = 1.0
"""A position or pose coordinate beyond this (m) is no reading of a part on a feeder's plate."""
PLAUSIBLE_RAD = 100.0
"""An angle beyond this (rad) is no camera's reading (they give (−π, π])."""


def implausible(sample: PositionSample) -> str | None:
    """What is wrong with ``sample``'s numbers (non-finite, or off any plate), or None: such a
    reading is a faulty sensor, never a position to learn from or store."""
    values = [("position", sample.position_m, PLAUSIBLE_M)]
    for part, (x, y, psi) in enumerate(sample.poses, start=1):
        values += [(f"part {part}'s x", x, PLAUSIBLE_M), (f"part {part}'s y", y, PLAUSIBLE_M),
                   (f"part {part}'s angle", psi, PLAUSIBLE_RAD)]  # fmt: skip
    for name, value, bound in values:
        if not (math.isfinite(value) and abs(value) <= bound):
            return f"an impossible {name}: {value!r}"
    return None


class SensorFeed:
    """Reads the sensor in its own thread so a slow frame never stalls the tick; ``first``: a
    reading already taken from it (arriving now)."""

    def __init__(
        self,
        sensor: PositionSensor,
        timeout_s: float,
        clock: Callable[[], float],
        first: PositionSample | None = None,
    ) -> None:
        self.sensor = sensor
        self.timeout_s = timeout_s
        self._clock = clock
        self._lock = threading.Lock()
        self._arrived = threading.Condition(self._lock)
        self._last: tuple[int, PositionSample] | None = None  # (arrivals so far, the latest)
        self._pending: list[tuple[float, PositionSample]] = [] if first is None else [(clock(), first)]
        self.lost: str | None = None
        self._closing = False
        stall.watch()
        self._thread = threading.Thread(target=self._run, name="sensor-feed", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._closing:
            started = time.monotonic()
            try:
                sample = self.sensor.read(self.timeout_s)
            except (SensorLost, OSError) as err:
                stalled = stall.stalled_since(started)
                if stalled > 0 and not self._closing:  # the silence was ours: listen again
                    log.warning("the daemon stood still %.2f s: the sensor's silence is judged again (%s)",
                                stalled, err)  # fmt: skip
                    continue
                if not self._closing:
                    self._lose(str(err) or type(err).__name__)
                return
            wrong = implausible(sample)
            if wrong is not None:
                self._lose(f"the sensor reported {wrong}")
                return
            with self._arrived:
                self._pending.append((self._clock(), sample))
                self._last = (1 if self._last is None else self._last[0] + 1, sample)
                self._arrived.notify_all()

    def _lose(self, reason: str) -> None:
        with self._arrived:
            self.lost = reason
            self._arrived.notify_all()

    def take(self) -> list[tuple[float, PositionSample]]:
        """Samples that arrived since the last call: (arrival loop time s, sample)."""
        with self._lock:
            out, self._pending = self._pending, []
        return out

    def next_sample(self, timeout_s: float) -> PositionSample:
        """The next sample to arrive after this call, for a reader besides the loop (which still
        takes it); :class:`SensorLost` when none comes within ``timeout_s`` or the sensor is lost."""
        with self._arrived:
            seen = 0 if self._last is None else self._last[0]
            arrived = self._arrived.wait_for(
                lambda: self.lost is not None or (self._last is not None and self._last[0] > seen), timeout_s
            )
            if self.lost is not None:
                raise SensorLost(self.lost)
            if not arrived or self._last is None:
                raise SensorLost(f"no poses within {timeout_s:g} s")
            return self._last[1]

    def close(self) -> None:
        """Stop reading and close the sensor's link."""
        self._closing = True
        with contextlib.suppress(SensorLost, OSError):
            self.sensor.close()
        self._thread.join(timeout=self.timeout_s + 1.0)
