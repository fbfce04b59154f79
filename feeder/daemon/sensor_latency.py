"""How long the policy waits after a burst: the sensor's latency as seen, with a margin and a cap.

A camera's frames arrive after exposure, encoding, transfer, decoding and
locating: on a loaded machine longer than the configured ``settle_s``.  The
policy's burst cycle (:mod:`feeder.daemon.burst_cycle`) records, per burst, the time from its first
step to the first reading that shows the part moved, and settles for the
longest of the last :data:`LATENCY_BURSTS` such delays times
:data:`LATENCY_MARGIN` when that is longer than ``settle_s``.
"""

from __future__ import annotations

LATENCY_BURSTS = 8
"""The sensor's latency is the longest seen over this many bursts ..."""
LATENCY_MARGIN = 1.25
"""... times this margin."""
MAX_SETTLE_S = 3.0
"""The longest wait after a burst, whatever the latency seen."""


class SensorLatency:
    """The sensor's latency as seen over the last :data:`LATENCY_BURSTS` bursts (s)."""

    def __init__(self) -> None:
        self._delays: list[float] = []

    @property
    def known(self) -> bool:
        """Whether any burst's motion has been seen yet."""
        return bool(self._delays)

    @property
    def latency_s(self) -> float:
        """The longest delay seen from a burst's start to the first reading that shows the part
        moved (s); 0 before the first."""
        return max(self._delays, default=0.0)

    def seen(self, delay_s: float) -> None:
        """A burst's motion showed ``delay_s`` after its first step."""
        self._delays = [*self._delays, delay_s][-LATENCY_BURSTS:]

    def settle_s(self, configured_s: float) -> float:
        """The wait after a burst: ``configured_s``, or the latency seen with its margin when
        longer, at most :data:`MAX_SETTLE_S`."""
        return min(MAX_SETTLE_S, max(configured_s, LATENCY_MARGIN * self.latency_s))
