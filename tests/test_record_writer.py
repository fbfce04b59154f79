"""The record writer's thread has a boundary: a record callback's bug drops that record, not the
thread (feeder/daemon/executor.py RecordWriter)."""

from __future__ import annotations

import logging
import threading

import pytest
from test_control_loop import TRUE, make_loop, run_job
from test_daemon_doubles import FakeWorld

from feeder.daemon.control_loop import Job, JobResult
from feeder.daemon.executor import RecordWriter
from feeder.daemon.status_report import loop_status

pytestmark = pytest.mark.timeout(60)


def bug() -> None:
    raise KeyError("status")  # a record callback's bug: neither the store's nor the disk's trouble


def test_a_failing_write_is_dropped_logged_and_the_writes_behind_it_go_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The old code's thread ended on the KeyError: the write behind it never ran."""
    writer = RecordWriter()
    written = threading.Event()
    try:
        writer.put(bug)
        writer.put(written.set)
        assert written.wait(5), "the writes behind a failing one were never made"
        writer.put(bug)
        assert writer.flush(5)
    finally:
        writer.close()
    assert (writer.dropped, writer.dropped_reason) == (2, "KeyError: 'status'")
    assert writer.unwritable is None and writer.pending() == 0
    failed = [r for r in caplog.records if "record write failed" in r.getMessage()]
    assert failed[0].levelno == logging.ERROR and failed[0].exc_info is not None  # the traceback
    assert "failed again" in failed[1].getMessage() and failed[1].exc_info is None  # a repeat: one line


def test_a_store_outage_is_still_held_and_retried_not_dropped() -> None:
    """An OSError is the store's trouble, not a bug: held at the head and retried, as before."""
    attempts: list[int] = []
    outage: list[str] = []

    def full_then_fine() -> None:
        attempts.append(1)
        if len(attempts) < 3:
            raise OSError("disk full")

    writer = RecordWriter(retry_s=0.01, on_unwritable=outage.append)
    try:
        writer.put(full_then_fine)
        assert writer.flush(5)
    finally:
        writer.close()
    assert len(attempts) == 3 and outage == ["disk full"] and writer.unwritable is None


@pytest.mark.parametrize("failing", ["on_start", "on_progress", "on_done"])
def test_a_moves_record_that_fails_still_answers_it_and_the_next_move(failing: str) -> None:
    """The old code: on_start's bug ended the writer before the move's end record, so the move
    was never answered; on_progress's and on_done's, the next move."""
    loop, _, _ = make_loop(FakeWorld(TRUE, scatter=0.03, noise_m=0.05e-6, seed=7))
    ended: list[JobResult] = []

    def fails_once(*_: object) -> None:
        if not ended:
            bug()

    try:
        first = Job("move", target_m=100e-6, **{failing: fails_once})
        result = run_job(loop, first)
        ended.append(result)
        second = run_job(loop, Job("move", target_m=0.0, on_done=ended.append), timeout=30)
    finally:
        loop.shutdown()
    assert result.status == "done" and second.status == "done"
    assert ended == [result, second]
    status = loop_status(loop, ())
    assert status["records_dropped"] >= 1 and status["record_dropped_reason"] == "KeyError: 'status'"
