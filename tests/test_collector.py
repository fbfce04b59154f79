"""The garbage collector run in the tick's slack (feeder/daemon/collector.py)."""

from __future__ import annotations

import gc
import threading
import time
import weakref
from collections.abc import Iterator

import pytest
from test_control_loop import TRUE, make_loop, run_job
from test_daemon_doubles import FakeWorld

from feeder.daemon.collector import TickCollector, due_generation
from feeder.daemon.control_loop import Job


class Cycle:
    """An object in a reference cycle: only the cyclic collector frees it."""

    def __init__(self) -> None:
        self.me = self


@pytest.fixture
def collections() -> Iterator[list[tuple[str, int]]]:
    """(thread name, generation) of every collection while the test runs."""
    seen: list[tuple[str, int]] = []

    def record(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            seen.append((threading.current_thread().name, info["generation"]))

    gc.callbacks.append(record)
    yield seen
    gc.callbacks.remove(record)


def test_the_due_generation_is_cpythons_own_choice() -> None:
    """At each automatic collection CPython has chosen its generation from the same counts and
    thresholds; its extra rule (old objects pending ≥ 1/4 of the long-lived) can only veto a
    full collection, and then it goes on down the generations as without one."""
    seen: list[tuple[tuple[int, int, int], int]] = []

    def record(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            seen.append((gc.get_count(), info["generation"]))

    assert gc.isenabled()
    # CPython's veto depends on the whole heap: a worker that ran other tests first holds enough
    # long-lived objects (~550 000 measured) that 100 000 survivors never reach a quarter of them,
    # and no full collection comes. Frozen, the heap is out of the count.
    gc.freeze()
    gc.collect()
    gc.callbacks.append(record)
    try:
        keep = [[Cycle() for _ in range(50)] for _ in range(2000)]  # survivors fill the old generations
        for _ in range(200_000):
            Cycle()
    finally:
        gc.callbacks.remove(record)
        gc.unfreeze()
    del keep
    thresholds = gc.get_threshold()
    assert {generation for _, generation in seen} == {0, 1, 2}, seen
    for (c0, c1, c2), theirs in seen:
        ours = due_generation((c0, c1, c2), thresholds)
        vetoed = due_generation((c0, c1, 0), thresholds)
        assert theirs == ours or (ours == 2 and theirs == vetoed), ((c0, c1, c2), theirs)
    assert due_generation((700, 0, 0), (700, 10, 10)) is None
    assert due_generation((701, 11, 11), (700, 10, 0)) == 1  # threshold 0: never that generation


def test_loops_share_the_take_over_and_the_last_hands_it_back() -> None:
    assert gc.isenabled() and gc.get_freeze_count() == 0
    first, second, off = TickCollector(), TickCollector(), TickCollector(active=False)
    first.take_over()
    second.take_over()
    off.take_over()
    assert not gc.isenabled() and gc.get_freeze_count() > 0
    first.hand_back()
    first.hand_back()  # twice: counted once
    assert not gc.isenabled()
    second.hand_back()
    off.hand_back()
    assert gc.isenabled() and gc.get_freeze_count() == 0
    gc.disable()
    try:  # a process that had turned collection off keeps it off
        first.take_over()
        first.hand_back()
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_while_a_loop_runs_only_its_tick_collects(collections: list[tuple[str, int]]) -> None:
    """Cyclic garbage made on another thread is collected, by the tick, between ticks."""
    loop, _, _ = make_loop(FakeWorld(TRUE, scatter=0.03, noise_m=0.05e-6, seed=7))
    try:
        time.sleep(0.05)
        assert not gc.isenabled()
        collections.clear()  # from the start on: any before the take-over ran where they fell
        sentinel = Cycle()
        gone = weakref.ref(sentinel)
        del sentinel
        for _ in range(100):
            for _ in range(1000):
                Cycle()
            time.sleep(0.002)
        deadline = time.monotonic() + 2
        while gone() is not None and time.monotonic() < deadline:
            time.sleep(0.01)
        result = run_job(loop, Job("move", target_m=30e-6))  # the loop still works
    finally:
        loop.shutdown()
    assert gone() is None and result.status == "done", result.reason
    threads = {name for name, _ in collections}
    assert threads == {"control-loop"}, collections
    assert {generation for _, generation in collections} >= {0, 1}
    timing = loop.timing()
    assert timing["collections"] == len(collections) and timing["collection_max_s"] > 0
    assert gc.isenabled() and gc.get_freeze_count() == 0
