"""The daemon's scheduling (feeder/daemon/realtime.py): real-time threads where allowed, never
inherited by the programs it starts, and the tick's wake-up helper."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import pytest

from feeder.daemon import realtime


def _fifo_allowed() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(1))
    except PermissionError:
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


needs_fifo = pytest.mark.skipif(
    not _fifo_allowed(), reason="SCHED_FIFO needs root, CAP_SYS_NICE or an rtprio limit"
)


@needs_fifo
def test_daemon_threads_run_below_the_tick_and_their_programs_at_ordinary_priority() -> None:
    seen: dict[str, object] = {}
    go, done = threading.Event(), threading.Event()

    def service() -> None:
        go.wait(5)
        seen["policy"] = os.sched_getscheduler(0)
        seen["priority"] = os.sched_getparam(0).sched_priority
        child = subprocess.run(
            [sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"],
            capture_output=True,
            text=True,
            check=True,
        )
        seen["child"] = int(child.stdout)
        done.set()

    def tick() -> None:
        seen["tick"] = realtime.raise_tick()
        seen["tick_priority"] = os.sched_getparam(0).sched_priority
        done.wait(10)

    threads = [threading.Thread(target=service), threading.Thread(target=tick)]
    for t in threads:
        t.start()
    time.sleep(0.05)
    assert realtime.raise_daemon_threads() >= 1  # the service thread (the tick raised itself)
    go.set()
    for t in threads:
        t.join(10)
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the host program's thread is left as it is
    assert seen["tick"] == "fifo" and seen["tick_priority"] == realtime.TICK_PRIORITY
    assert seen["policy"] & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO
    assert seen["priority"] == realtime.SERVICE_PRIORITY < realtime.TICK_PRIORITY
    assert seen["child"] == os.SCHED_OTHER  # reset on fork: no program inherits real time


def test_the_tick_sleeps_to_its_deadline_and_leaves_the_switch_interval_as_it_was() -> None:
    before = sys.getswitchinterval()
    for clock in (time.monotonic, lambda: time.monotonic()):  # the C helper, then Python's sleep
        deadline = clock() + 0.02
        realtime.sleep_until(deadline, clock)
        woke = clock()
        assert deadline <= woke < deadline + 0.5  # never early
        assert sys.getswitchinterval() == before
    realtime.sleep_until(time.monotonic() - 1.0)  # a deadline past: returns at once
    assert sys.getswitchinterval() == before


def test_the_wake_helper_is_built() -> None:
    # make test installs the package with it; without a C compiler the tick sleeps in Python
    if realtime._tick_wake is None:
        pytest.skip("feeder.daemon._tick_wake was not built (no C compiler at install)")
    with pytest.raises(ValueError, match="urgent_s"):
        realtime._tick_wake.sleep_until(time.monotonic(), 0.0)
    with pytest.raises(ValueError, match="finite"):
        realtime._tick_wake.sleep_until(float("nan"), 20e-6)
