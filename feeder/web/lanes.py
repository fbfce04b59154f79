"""Where the console's calls into the daemon run: off the event loop, and never where a waiting
move can keep a STOP out.

The daemon's request handler blocks (:meth:`~feeder.daemon.service.Daemon.handle`: a move with
``wait`` returns when the move ends), so the console calls it on threads.  Until 2026-11-27 every
call went through the one thread pool starlette shares (anyio's, 40 threads): 40 waiting
``POST /api/move {"queue": true}`` held all of them, and ``POST /api/stop`` went unanswered until
a move ended.  Now:

- :class:`UrgentLane`: ``stop`` and ``status`` on threads of their own.  Both are quick (a stop
  takes the daemon's lock, empties its queue and sets a flag; a status takes a snapshot; the
  handler first stands back for the tick, at most 5 ms), so two threads answer them promptly
  whatever else waits.  They are threads, not the event loop, so that a lock held a while in the
  daemon delays the stop alone, not every page.
- :class:`MoveLane`: moves, jogs and calibrations, each on a thread of its own while it waits
  for its result, at most :data:`MAX_WAITING_MOVES` at once; beyond, 503 at once.
- history: starlette's shared pool, which nothing waits in for long any more.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from feeder.web.requests import ApiError

MAX_WAITING_MOVES = 16
"""Move, jog and calibrate requests the console holds at once (a waiting move holds one until it
ends); more get 503.  Far above what a page sends (2 moves a second, a burst of 5)."""
URGENT_THREADS = 2
"""Threads answering ``stop`` and ``status`` (the live feed asks one status at a time)."""

Call = Callable[[dict[str, Any]], dict[str, Any]]


class UrgentLane:
    """Quick daemon calls (``stop``, ``status``) on a small pool of their own."""

    def __init__(self, threads: int = URGENT_THREADS) -> None:
        self._executor = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="console-urgent")

    async def run(self, call: Call, request: dict[str, Any]) -> dict[str, Any]:
        return await asyncio.get_running_loop().run_in_executor(self._executor, call, request)

    def close(self) -> None:
        self._executor.shutdown(wait=False, cancel_futures=True)


class MoveLane:
    """Daemon calls that may wait for a move's result: each on a thread of its own (a daemon
    thread: a move still waiting at exit does not hold the process), at most ``slots`` at once
    (default :data:`MAX_WAITING_MOVES`)."""

    def __init__(self, slots: int | None = None) -> None:
        self.slots = MAX_WAITING_MOVES if slots is None else slots
        self._lock = threading.Lock()
        self._busy = 0

    async def run(self, call: Call, request: dict[str, Any]) -> dict[str, Any]:
        """``call(request)``'s reply; :class:`ApiError` 503 when ``slots`` calls already run."""
        with self._lock:
            if self._busy >= self.slots:
                raise ApiError(
                    503,
                    f"too many moves waiting for their result (at most {self.slots}); "
                    "retry when one has ended, or send wait: false",
                )
            self._busy += 1
        loop = asyncio.get_running_loop()
        future: asyncio.Future[dict[str, Any]] = loop.create_future()

        def settle(reply: dict[str, Any] | None, error: Exception | None) -> None:
            if future.done():  # the request was cancelled meanwhile
                return
            if error is not None:
                future.set_exception(error)
            else:
                assert reply is not None
                future.set_result(reply)

        def work() -> None:
            reply: dict[str, Any] | None = None
            error: Exception | None = None
            try:
                reply = call(request)
            except Exception as err:
                # the move thread's one boundary: whatever the daemon's handler raises is handed
                # to the request awaiting it and raised there (a 500 with the console's message)
                error = err
            finally:
                with self._lock:
                    self._busy -= 1
            try:
                loop.call_soon_threadsafe(settle, reply, error)
            except RuntimeError:  # the console's event loop closed while the move waited
                return

        threading.Thread(target=work, name="console-move", daemon=True).start()
        return await future
