"""The daemon beside a state database another program has locked (a backup, ``sqlite3`` with a
transaction open): each record write waits out SQLite's busy timeout holding the store."""

from __future__ import annotations

import sqlite3
import threading
from pathlib import Path
from typing import Any

import pytest
from test_daemon_service import start, wait_for

from feeder.daemon.requests import _new_job

pytestmark = pytest.mark.timeout(60)

STATUS_WAIT_S = 3.0
"""Well within SQLite's busy timeout (10 s), which the store's write waits out."""


def test_status_answers_while_a_record_write_waits_for_a_locked_database(short_dir: Path) -> None:
    """``status`` read the last known position from the store, behind the write in flight: a
    waiting move's client, whose heartbeat is a ``status``, gave up on a daemon that was about to
    answer it (and ``feeder status`` hung as long)."""
    daemon, _ = start(short_dir)
    other = sqlite3.connect(short_dir / "state" / "f.sqlite", isolation_level=None)
    answers: list[dict[str, Any]] = []
    try:
        wait_for(lambda: daemon.loop.position_m is not None)
        job = _new_job(daemon, "move", 400e-6, None)
        assert daemon.run(job, queue=False) == (0, None)
        wait_for(lambda: job.recorded)
        other.execute("BEGIN IMMEDIATE")  # the database's write lock, held
        wait_for(lambda: daemon.loop.writer.pending() >= 2)  # the first write waits for it
        asking = threading.Thread(target=lambda: answers.append(daemon.status()), name="status")
        asking.start()
        asking.join(STATUS_WAIT_S)
        assert answers, f"status was not answered within {STATUS_WAIT_S:g} s"
    finally:
        other.rollback()
        other.close()
        daemon.shutdown()
    assert answers[0]["state"] in ("moving", "idle")
    assert isinstance(answers[0]["last_known_position_m"], float)
