"""A recurring trouble logged without flooding the log (descriptors run out on every accept)."""

from __future__ import annotations

import logging
import time


class LogThrottle:
    """Logs a recurring trouble's first occurrence, then at most once every ``every_s``, saying
    how many occurrences went unlogged meanwhile."""

    def __init__(self, logger: logging.Logger, every_s: float = 60.0) -> None:
        self._logger = logger
        self._every_s = every_s
        self._logged_s: float | None = None
        self._unlogged = 0

    def warning(self, message: str, *args: object) -> None:
        now = time.monotonic()
        if self._logged_s is not None and now - self._logged_s < self._every_s:
            self._unlogged += 1
            return
        if self._unlogged:
            message += f" ({self._unlogged} more since the last such line)"
        self._logger.warning(message, *args)
        self._logged_s, self._unlogged = now, 0
