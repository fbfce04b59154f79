"""The console's live status (docs/console.md): one snapshot of the daemon's ``status`` shared
by every page and ``/api/status``, taken every :data:`LIVE_PERIOD_S` while a page watches.

Taking a snapshot (a call into the daemon, on the urgent lane's thread) and sending one (the
event loop's work) overlap: while pages watch, one task takes them at a fixed rate and each page
sends every new one as it comes.  A page's rate is then held back by the slower of the two, not
by their sum, which on a loaded machine is the difference between 30 and ~15 pushes a second.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import time
from collections.abc import AsyncIterator, Callable
from typing import Any

from feeder.web.lanes import UrgentLane

LIVE_PERIOD_S = 1 / 30
"""Status pushes to each live client: 30 per second."""
STATUS_MAX_AGE_S = 0.025
"""A status snapshot is shared by the requests within this time of it."""


class LiveFeed:
    """The newest status, shared by every live client and ``/api/status``: at most one
    ``status`` request reaches the daemon per :data:`STATUS_MAX_AGE_S` however many pages
    and scripts ask (a burst of requests costs the daemon one)."""

    def __init__(self, handle: Callable[[dict[str, Any]], dict[str, Any]], lane: UrgentLane) -> None:
        self._handle = handle
        self._lane = lane
        self._lock = asyncio.Lock()
        self._changed = asyncio.Condition()
        self._status: dict[str, Any] = {}
        self._message = ""
        self._number = 0  # of the newest snapshot: 1, 2, ...
        self._taken_s = -math.inf
        self._watchers = 0
        self._pump: asyncio.Task[None] | None = None

    async def status(self) -> dict[str, Any]:
        """The daemon's status, at most :data:`STATUS_MAX_AGE_S` old."""
        await self._refresh()
        return self._status

    @contextlib.asynccontextmanager
    async def watched(self) -> AsyncIterator[int]:
        """While a page watches: snapshots are taken every :data:`LIVE_PERIOD_S` until the last
        page has gone.  Gives the number of the newest snapshot so far (the page's are newer)."""
        self._watchers += 1
        if self._pump is None or self._pump.done():
            self._pump = asyncio.create_task(self._take_every_period())
        try:
            yield self._number
        finally:
            self._watchers -= 1
            if self._watchers == 0 and self._pump is not None:
                self._pump.cancel()
                self._pump = None

    async def next_message(self, seen: int, unless: asyncio.Future[Any]) -> tuple[int, str] | None:
        """The first status message newer than snapshot number ``seen`` as
        ``(number, text)`` (``time_s`` in it: the wall clock before the snapshot was taken), or
        None when ``unless`` is done first; within :meth:`watched`.  What stopped the snapshots
        (the daemon's handler raising) is raised here."""
        pump = self._pump
        if pump is None:
            raise RuntimeError("next_message outside watched()")
        newer = asyncio.ensure_future(self._newer_than(seen))
        done, _ = await asyncio.wait({newer, pump, unless}, return_when=asyncio.FIRST_COMPLETED)
        if newer in done:
            return newer.result()
        newer.cancel()
        if pump in done:
            pump.result()  # raises what stopped it (it never returns)
        return None

    async def _newer_than(self, seen: int) -> tuple[int, str]:
        async with self._changed:
            await self._changed.wait_for(lambda: self._number > seen)
            return self._number, self._message

    async def _take_every_period(self) -> None:
        deadline = time.monotonic()
        while True:
            deadline = max(deadline + LIVE_PERIOD_S, time.monotonic())  # a fixed rate, never a burst
            await self._refresh()
            await asyncio.sleep(max(0.0, deadline - time.monotonic()))

    async def _refresh(self) -> None:
        async with self._lock:
            asked_s = time.monotonic()
            if asked_s - self._taken_s < STATUS_MAX_AGE_S:
                return
            wall = time.time()
            status = await self._lane.run(self._handle, {"cmd": "status"})
            message = json.dumps(
                {"type": "status", "time_s": wall, "status": status}, allow_nan=False, default=str
            )
            async with self._changed:
                # its age counts from the asking: a status that takes longer than the period to
                # answer is followed by the next, not skipped as fresh
                self._status, self._message, self._taken_s = status, message, asked_s
                self._number += 1
                self._changed.notify_all()
