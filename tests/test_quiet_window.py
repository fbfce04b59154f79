"""The request threads' quiet window before each tick (feeder/daemon/quiet_window.py) and the
console's event loop that keeps it (feeder/web/server.py)."""

from __future__ import annotations

import asyncio
import threading
import time

from feeder.daemon.quiet_window import QuietWindow, quiet_event_loop


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def held_for(window: QuietWindow) -> float:
    """Seconds one hold() took on this thread."""
    began = time.monotonic()
    window.hold()
    return time.monotonic() - began


def serve_in(window: QuietWindow, delay_s: float) -> list[float]:
    """The tick, on a thread: served after ``delay_s``; the list gets the time it was."""
    served_at: list[float] = []

    def tick() -> None:
        time.sleep(delay_s)
        served_at.append(time.monotonic())
        window.served()

    threading.Thread(target=tick).start()
    return served_at


def test_outside_the_window_a_request_thread_runs_on() -> None:
    clock = Clock()
    window = QuietWindow(guard_s=2e-3, max_hold_s=1.0, clock=clock)
    assert held_for(window) < 0.05  # no deadline announced: never holds
    window.due(clock.now + 3e-3)  # 3 ms ahead: the window opens 1 ms from now
    assert held_for(window) < 0.05
    window.served()
    clock.now += 2.5e-3  # past that deadline, the tick served: runs on
    assert held_for(window) < 0.05
    assert window.holds == 0


def test_inside_the_window_a_request_thread_waits_until_the_tick_is_served() -> None:
    clock = Clock()
    window = QuietWindow(guard_s=2e-3, max_hold_s=10.0, clock=clock)
    window.due(clock.now + 1e-3)  # 1 ms ahead: open
    served_at = serve_in(window, 0.2)
    window.hold()
    returned = time.monotonic()
    assert served_at and returned >= served_at[0]
    assert window.holds == 1


def test_a_stalled_tick_holds_a_request_thread_at_most_max_hold_past_its_deadline() -> None:
    window = QuietWindow(guard_s=0.1, max_hold_s=0.2)
    window.due(time.monotonic() + 0.05)  # never served
    waited = held_for(window)
    assert 0.2 <= waited < 0.6  # 0.05 s to the deadline + 0.2 s, not forever
    assert window.holds == 1


def test_the_consoles_event_loop_runs_no_callback_while_the_window_is_open() -> None:
    window = QuietWindow(guard_s=10.0, max_hold_s=10.0)
    loop = quiet_event_loop(window)
    ran: list[float] = []

    async def request() -> None:
        ran.append(time.monotonic())
        await asyncio.sleep(0)
        ran.append(time.monotonic())

    try:
        began = time.monotonic()
        loop.run_until_complete(request())  # closed: runs at once
        assert ran[-1] - began < 0.1
        ran.clear()
        window.due(time.monotonic() + 1.0)  # open from now (10 s guard) until served
        served_at = serve_in(window, 0.2)
        loop.run_until_complete(request())
        assert served_at and min(ran) >= served_at[0]
        assert window.holds >= 1
    finally:
        loop.close()
