"""A stop, or the shutdown, that arrives while a move is being handed to the loop (found by a
review of the daemon's threads; each test holds a thread at the critical point)."""

from __future__ import annotations

import sqlite3
import threading
from pathlib import Path
from typing import Any

import pytest
from test_daemon_doubles import FakeSensor
from test_daemon_service import start, wait_for

from feeder.daemon.requests import _new_job
from feeder.daemon.service import Daemon

pytestmark = pytest.mark.timeout(60)


def _held_before_the_handover(daemon: Daemon, thread_name: str) -> tuple[threading.Event, threading.Event]:
    """Hold ``thread_name`` where the daemon prepares a job for the loop (the camera's
    recalibration and the calibration's read: a while), before it hands it over."""
    arrived, release = threading.Event(), threading.Event()
    prepare = daemon._uncalibrated

    def held() -> str | None:
        if threading.current_thread().name == thread_name:
            arrived.set()
            assert release.wait(10)
        return prepare()

    daemon._uncalibrated = held  # type: ignore[method-assign]
    return arrived, release


def test_a_stop_while_a_queued_move_is_handed_to_the_loop_refuses_it(short_dir: Path) -> None:
    """The stop found the queue empty and no job in the loop, and the queued move then ran to
    its end (37 steps)."""
    daemon, _ = start(short_dir)
    try:
        wait_for(lambda: daemon.loop.position_m is not None)
        first = _new_job(daemon, "move", 20e-6, None)
        assert daemon.run(first, queue=False) == (0, None)
        queued = _new_job(daemon, "move", 120e-6, None)
        assert daemon.run(queued, queue=True) == (1, None)
        arrived, release = _held_before_the_handover(daemon, "queue")
        assert first.done.wait(20)
        assert arrived.wait(10)
        daemon.stop()
        release.set()
        assert queued.done.wait(10)
        assert queued.result is not None
        assert (queued.result.status, queued.result.reason) == ("refused", "stop requested")
        assert queued.result.steps == 0
    finally:
        daemon.shutdown()


def test_a_stop_while_a_direct_move_is_prepared_refuses_it(short_dir: Path) -> None:
    daemon, _ = start(short_dir)
    try:
        wait_for(lambda: daemon.loop.position_m is not None)
        arrived, release = _held_before_the_handover(daemon, "mover")
        job = _new_job(daemon, "move", 120e-6, None)
        answers: list[tuple[int, str | None]] = []
        mover = threading.Thread(target=lambda: answers.append(daemon.run(job, queue=False)), name="mover")
        mover.start()
        assert arrived.wait(10)
        daemon.stop()
        release.set()
        mover.join(10)
        assert answers == [(0, "stop requested")]
        assert not daemon.loop.busy()
    finally:
        daemon.shutdown()


def test_a_move_asked_for_once_the_shutdown_has_begun_is_refused(short_dir: Path) -> None:
    """It was handed to the loop after the shutdown's one stop and played bursts until the
    shutdown's wait ran out."""
    daemon, links = start(short_dir)
    wait_for(lambda: daemon.loop.position_m is not None)
    stopped, go_on = threading.Event(), threading.Event()
    request_stop = daemon.loop.request_stop

    def held_stop(reason: str = "stop requested") -> bool:
        answer = request_stop(reason)
        if reason == "daemon shutting down":
            stopped.set()
            assert go_on.wait(10)
        return answer

    daemon.loop.request_stop = held_stop  # type: ignore[method-assign]
    shutting = threading.Thread(target=daemon.shutdown)
    shutting.start()
    try:
        assert stopped.wait(10)
        job = _new_job(daemon, "move", 400e-6, None)
        steps_before = sum(1 for call in links.amplifiers[0].calls if call == "step")
        assert daemon.run(job, queue=False) == (0, "daemon shutting down")
        assert daemon.run(_new_job(daemon, "move", 400e-6, None), queue=True) == (0, "daemon shutting down")
    finally:
        go_on.set()
        shutting.join(30)
    assert sum(1 for call in links.amplifiers[0].calls if call == "step") == steps_before


def test_an_error_in_a_tick_is_a_lost_link_not_the_loops_end(short_dir: Path) -> None:
    """One exception from the policy on the tick thread ended the loop for good: the move never
    ended, a stop only set a flag, and the axis stayed enabled (grounded only by the shutdown)."""
    daemon, links = start(short_dir)
    try:
        wait_for(lambda: daemon.loop.position_m is not None)
        amplifier = links.amplifiers[0]
        tick, failing = daemon.loop.policy.tick, threading.Event()

        def failing_tick(now: float) -> Any:
            if failing.is_set() and threading.current_thread().name == "control-loop":
                failing.clear()
                raise RuntimeError("a navigator bug")
            return tick(now)

        daemon.loop.policy.tick = failing_tick  # type: ignore[method-assign]
        job = _new_job(daemon, "move", 300e-6, None)
        assert daemon.run(job, queue=False) == (0, None)
        wait_for(lambda: not amplifier.grounded)  # enabled: under way
        failing.set()
        assert job.done.wait(10)
        assert job.result is not None and job.result.status == "fault"
        assert "control loop error: RuntimeError: a navigator bug" in (job.result.reason or "")
        wait_for(lambda: amplifier.grounded)  # the lost link's path grounds it
        wait_for(lambda: daemon.loop.fault is None and len(links.amplifiers) == 2)  # reconnected
        wait_for(lambda: daemon.loop.position_m is not None)
        again = _new_job(daemon, "move", 120e-6, None)
        assert daemon.run(again, queue=False) == (0, None)
        assert again.done.wait(30) and again.result is not None and again.result.status == "done"
    finally:
        daemon.shutdown()


def test_a_queued_move_that_cannot_be_handed_over_is_refused_and_the_queue_goes_on(short_dir: Path) -> None:
    """An unforeseen error there (a raw sqlite3 error from the calibration's read) ended the queue
    thread: the move was never answered and the moves queued behind never ran."""
    daemon, _ = start(short_dir)
    try:
        wait_for(lambda: daemon.loop.position_m is not None)
        saved, failures = daemon.camera_calibration.saved, [sqlite3.OperationalError("disk I/O error")]

        def failing_saved() -> bool:
            if threading.current_thread().name == "queue" and failures:
                raise failures.pop()
            return saved()

        daemon.camera_calibration.saved = failing_saved  # type: ignore[method-assign]
        running = _new_job(daemon, "move", 20e-6, None)
        assert daemon.run(running, queue=False) == (0, None)
        first, second = _new_job(daemon, "move", 120e-6, None), _new_job(daemon, "move", 60e-6, None)
        assert daemon.run(first, queue=True) == (1, None) and daemon.run(second, queue=True) == (2, None)
        assert first.done.wait(20) and first.result is not None
        assert (first.result.status, first.result.reason) == ("refused", "OperationalError: disk I/O error")
        assert second.done.wait(30) and second.result is not None and second.result.status == "done"
    finally:
        daemon.shutdown()


def test_a_move_ended_before_the_store_failed_is_answered_during_the_outage(short_dir: Path) -> None:
    """A write in flight when the move ended failed just after: the move's own record waited
    behind it for as long as the store stayed unwritable, and so did its caller."""
    daemon, _ = start(short_dir)
    armed, in_flight, fail, broken = (threading.Event() for _ in range(4))
    try:
        wait_for(lambda: daemon.loop.position_m is not None)
        save = daemon.store.save_position

        def failing_save(*args: Any, **kwargs: Any) -> None:
            if armed.is_set() and not broken.is_set():
                in_flight.set()
                assert fail.wait(10)  # an fsync on a failing disk
                broken.set()
            if broken.is_set():
                raise sqlite3.OperationalError("disk I/O error")
            save(*args, **kwargs)

        daemon.loop.on_position = failing_save
        job = _new_job(daemon, "move", 150e-6, None)
        assert daemon.run(job, queue=False) == (0, None)
        wait_for(lambda: job.recorded)
        armed.set()
        wait_for(lambda: daemon.loop.current_job() is None, 30)  # ended in the loop
        assert in_flight.wait(10)
        fail.set()
        assert job.done.wait(5), "the caller waits while the store stays unwritable"
        assert job.result is not None and job.result.status == "done"
        assert daemon.loop.writer.unwritable is not None  # still failing
    finally:
        broken.set()
        daemon.shutdown()


def test_two_sensor_replacements_at_once_leave_no_sensor_read_for_nothing(short_dir: Path) -> None:
    """A recalibration and a reconnect replacing the sensor together both closed the same old
    feed, and the second orphaned the first's new sensor: read on, never closed."""
    daemon, links = start(short_dir)
    try:
        wait_for(lambda: daemon.loop.position_m is not None)
        old = daemon.loop._feed
        other_started = threading.Event()
        close = old.close

        def slow_close() -> None:  # the first replacement closes the old feed slowly
            other_started.wait(1.0)
            close()

        old.close = slow_close  # type: ignore[method-assign]
        one, two = FakeSensor(links.world), FakeSensor(links.world)
        first = threading.Thread(target=daemon.loop.replace_sensor, args=(one,))
        first.start()
        second = threading.Thread(target=lambda: (other_started.set(), daemon.loop.replace_sensor(two)))
        second.start()
        first.join(10)
        second.join(10)
        in_use = daemon.loop.sensor
        assert in_use in (one, two)
        assert (two if in_use is one else one).closed  # the one replaced is not read on
    finally:
        daemon.shutdown()
