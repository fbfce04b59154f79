"""Reconnecting a lost link: its backoff, which failures are logged, when a sensor is back.

A link that opens is not yet a link that works: a camera object opens, and a socket to a
camera connects, before any frame arrives.  So a re-opened sensor counts as restored only once
it has delivered a first plausible reading (:func:`first_reading`); until then the daemon stays
in ``fault``, nothing is logged as restored, and the reconnect tries again after its backoff.

:class:`Outage` is the reconnect's state machine, without I/O or sleeps: it is told each
attempt's outcome and the time, and answers the delay before the next attempt and the line to
log, if any.  It logs the first failure and then at most one line every :data:`OUTAGE_LOG_S`,
so a camera that stays down leaves a line now and then, not one per attempt.
"""

from __future__ import annotations

import contextlib

from feeder.daemon.sensor_feed import implausible
from feeder.drivers.sensor import PositionSample, PositionSensor, SensorLost

BACKOFF_FIRST_S = 0.2
"""The wait before the first attempt (s); it doubles after each failure..."""
BACKOFF_MAX_S = 5.0
"""... up to this (s)."""
OUTAGE_LOG_S = 60.0
"""After the first failed attempt, a continued outage is logged at most this often (s)."""


class Outage:
    """One lost link's reconnect attempts (see the module doc); ``started_s``: when it was lost."""

    def __init__(
        self,
        link: str,
        started_s: float,
        first_s: float = BACKOFF_FIRST_S,
        max_s: float = BACKOFF_MAX_S,
        log_every_s: float = OUTAGE_LOG_S,
    ) -> None:
        self.link = link
        self.started_s = started_s
        self.delay_s = first_s
        """The wait before the next attempt (s)."""
        self.attempts = 0
        """Attempts made so far, the successful one included."""
        self._max_s = max_s
        self._log_every_s = log_every_s
        self._logged_s: float | None = None

    def failed(self, error: str, now_s: float) -> str | None:
        """An attempt failed with ``error`` at ``now_s``: the backoff doubles; the line to log,
        or None while the last one is recent."""
        self.attempts += 1
        self.delay_s = min(2 * self.delay_s, self._max_s)
        if self._logged_s is not None and now_s - self._logged_s < self._log_every_s:
            return None
        first = self._logged_s is None
        self._logged_s = now_s
        if first:
            return f"{self.link} reconnect attempt {self.attempts} failed: {error}"
        return (
            f"{self.link} still lost after {self.attempts} reconnect attempts in "
            f"{now_s - self.started_s:.0f} s: {error}"
        )

    def restored(self, now_s: float) -> str:
        """The attempt at ``now_s`` succeeded: the line to log (once per outage)."""
        self.attempts += 1
        return f"{self.link} link restored after {self.attempts} attempts ({now_s - self.started_s:.1f} s)"


def first_reading(sensor: PositionSensor, timeout_s: float) -> PositionSample:
    """The re-opened ``sensor``'s first reading within ``timeout_s``.

    Raises :class:`SensorLost` (or the link's ``OSError``) when none comes or it is no
    plausible reading; the sensor is then closed.
    """
    try:
        sample = sensor.read(timeout_s)
        wrong = implausible(sample)
        if wrong is not None:
            raise SensorLost(f"the sensor reported {wrong}")
    except (SensorLost, OSError):
        with contextlib.suppress(SensorLost, OSError):
            sensor.close()
        raise
    return sample
