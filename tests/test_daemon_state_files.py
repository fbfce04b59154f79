"""The daemon's state database on disk while the daemon runs (the in-process fake world as
hardware): removed or replaced under it, and what a move learns kept as it is learned."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_daemon_service import start
from test_store import stored_targets

from feeder.daemon.client import Client
from feeder.daemon.store import Store

pytestmark = pytest.mark.timeout(60)


def test_a_state_database_removed_under_the_daemon_refuses_moves_naming_it(short_dir: Path) -> None:
    """The daemon went on moving and recording into the unlinked file: its history was lost at
    shutdown, and its WAL, left at the path, was taken in by the next daemon's new database."""
    daemon, _ = start(short_dir)
    database = short_dir / "state" / "f.sqlite"
    try:
        with Client(short_dir / "run" / "f.sock") as client:
            assert client.request("move", target_m=60e-6)["ok"]
            database.unlink()
            moved = client.request("move", target_m=0.0)
            status = client.request("status")
    finally:
        daemon.shutdown()
    why = f"{database}: the state database was removed or moved away while the daemon had it open"
    assert not moved["ok"] and why in str(moved)
    assert status["moves_refused"] is not None and why in status["moves_refused"]
    assert status["store_unwritable"] is not None and why in status["store_unwritable"]
    (saved,) = database.parent.glob("f.sqlite.*.bak")  # what the daemon held, for the user
    assert stored_targets(saved) == [60e-6]
    assert not database.exists()
    assert stored_targets(database) == []  # the next daemon starts afresh, nothing of the old WAL in it


def test_a_state_database_replaced_under_the_daemon_is_left_as_it_was_put(short_dir: Path) -> None:
    """The daemon's WAL was applied to the replacement: it then held the daemon's history."""
    backup = Store(short_dir / "backup.sqlite")
    backup.begin_move(7e-6, 0.0)
    backup.close()
    daemon, _ = start(short_dir)
    database = short_dir / "state" / "f.sqlite"
    try:
        with Client(short_dir / "run" / "f.sock") as client:
            assert client.request("move", target_m=60e-6)["ok"]
            (short_dir / "backup.sqlite").replace(database)
            moved = client.request("move", target_m=0.0)
            status = client.request("status")
    finally:
        daemon.shutdown()
    assert not moved["ok"] and "the state database was replaced by another file" in str(moved)
    assert "restart the daemon to use the new file" in status["moves_refused"]
    assert stored_targets(database) == [7e-6]
    (saved,) = database.parent.glob("f.sqlite.*.bak")
    assert stored_targets(saved) == [60e-6]


def test_steps_learned_by_a_move_outlive_a_daemon_killed_before_its_end(short_dir: Path) -> None:
    """They were stored with the move's end only: a daemon killed mid-move (its end never
    recorded, as here) came back with the seed steps, as if it had learned nothing."""
    daemon, _ = start(short_dir)
    try:
        seed = daemon.status()["estimates"]["coarse/forward"]
        daemon.records.finish = lambda *args: None  # type: ignore[method-assign]  # killed: no end
        with Client(short_dir / "run" / "f.sock") as client:
            client.request("move", target_m=600e-6)
            learned = client.request("status")["estimates"]["coarse/forward"]
    finally:
        daemon.shutdown()
    assert seed["steps"] == 0 and learned["steps"] > 0
    again, _ = start(short_dir)
    try:
        status = again.status()
    finally:
        again.shutdown()
    assert len(status["interrupted_moves"]) == 1  # the move's end was never recorded
    kept = status["estimates"]["coarse/forward"]
    assert 0 < kept["steps"] <= learned["steps"]  # learned up to its last burst's start
    assert abs(kept["step_m"] - 3.0e-6) < abs(seed["step_m"] - 3.0e-6)  # towards the true step
