"""The state database: round trips, crash recovery (SIGKILL mid-write), refusal of bad files."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from feeder.daemon.move_records import MoveRecords
from feeder.daemon.store import SCHEMA_VERSION, Calibration, Store, StoreError

ROOT = Path(__file__).resolve().parents[1]


def test_round_trip(tmp_path: Path) -> None:
    store = Store(tmp_path / "state" / "feeder.sqlite")
    store.save_calibration(Calibration("a/coarse/forward", 3.1e-6, 1e-14, 20, 1.0))
    store.save_calibration(Calibration("a/coarse/forward", 3.2e-6, 4e-15, 40, 2.0, 0.9e-6, 3e-14, -2e-15))
    move = store.begin_move(100e-6, 0.0)
    store.finish_move(
        move,
        status="done",
        reason="within tolerance",
        reached_m=100.4e-6,
        steps=33,
        bursts=4,
        step_forward_m=3.2e-6,
        step_backward_m=None,
    )
    store.save_position(100.4e-6)
    store.close()

    again = Store(tmp_path / "state" / "feeder.sqlite")
    assert again.calibration("a/coarse/forward") == Calibration(
        "a/coarse/forward", 3.2e-6, 4e-15, 40, 2.0, 0.9e-6, 3e-14, -2e-15
    )
    (row,) = again.moves()
    assert row["status"] == "done" and row["steps"] == 33
    assert row["error_m"] == pytest.approx(0.4e-6, rel=1e-9)
    pos = again.position()
    assert pos is not None and pos.position_m == 100.4e-6
    assert oct((tmp_path / "state").stat().st_mode & 0o777) == "0o700"
    assert oct((tmp_path / "state" / "feeder.sqlite").stat().st_mode & 0o777) == "0o600"
    mode = sqlite3.connect(tmp_path / "state" / "feeder.sqlite").execute("PRAGMA journal_mode").fetchone()[0]
    assert mode == "wal"


def test_running_moves_become_interrupted(tmp_path: Path) -> None:
    store = Store(tmp_path / "s.sqlite")
    first = store.begin_move(1e-3, 0.0)
    store.finish_move(
        first,
        status="done",
        reason="",
        reached_m=1e-3,
        steps=1,
        bursts=1,
        step_forward_m=None,
        step_backward_m=None,
    )
    second = store.begin_move(2e-3, 1e-3)
    store.progress_move(second, steps=120, bursts=3)  # the bursts commanded before the kill
    store.progress_move(first, steps=999, bursts=9)  # a finished move's record stays as it ended
    assert store.interrupt_running_moves() == [second]
    moves = store.moves()
    ended = [(m["status"], m["steps"], m["bursts"]) for m in moves]
    assert ended == [("done", 1, 1), ("interrupted", 120, 3)]
    assert moves[1]["reason"].endswith("steps: as commanded")
    assert store.interrupt_running_moves() == []


WRITER = """
import sys, time
from pathlib import Path
from feeder.daemon.store import Calibration, Store
store = Store(Path(sys.argv[1]))
i = 0
while True:
    i += 1
    move = store.begin_move(i * 1e-6, 0.0)
    store.save_calibration(Calibration("k", i * 1e-9, 1e-18, i, time.time()))
    store.finish_move(move, status="done", reason="", reached_m=i * 1e-6, steps=i, bursts=1,
                      step_forward_m=i * 1e-9, step_backward_m=None)
    store.save_position(i * 1e-6)
    if i == 1:
        print("ready", flush=True)  # one move committed: a loaded machine may take long for it
"""


@pytest.mark.timeout(60)
def test_sigkill_mid_write_leaves_a_consistent_database(tmp_path: Path) -> None:
    path = tmp_path / "crash.sqlite"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for round_ in range(3):
        proc = subprocess.Popen(
            [sys.executable, "-c", WRITER, str(path)], env=env, stdout=subprocess.PIPE, text=True
        )
        assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        time.sleep(0.3)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        store = Store(path)
        assert store.integrity_ok()
        moves = store.moves(limit=1_000_000)
        assert moves, "the writer committed nothing"
        # every move but possibly the last is complete; transactions are never half applied
        assert all(m["status"] in ("done", "interrupted") for m in moves[:-1])
        assert sum(m["status"] == "interrupted" for m in moves) <= round_
        assert moves[-1]["status"] in ("done", "running")
        done = [m for m in moves if m["status"] == "done"]
        cal = store.calibration("k")
        assert cal is not None and cal.steps >= done[-1]["steps"]  # saved before finish
        store.interrupt_running_moves()
        store.close()


def test_refuses_a_file_that_is_not_a_database(tmp_path: Path) -> None:
    path = tmp_path / "junk.sqlite"
    path.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(StoreError):
        Store(path)
    assert path.read_bytes() == b"this is not sqlite" * 100


def test_refuses_a_newer_schema(tmp_path: Path) -> None:
    path = tmp_path / "new.sqlite"
    Store(path).close()
    conn = sqlite3.connect(path)
    conn.execute("UPDATE meta SET value = '99' WHERE key = 'schema_version'")
    conn.commit()
    conn.close()
    with pytest.raises(StoreError, match="newer"):
        Store(path)


def test_a_version_1_database_is_migrated(tmp_path: Path) -> None:
    """Version 1 stored the step only; its rows gain the offset prior of a fresh seed."""
    path = tmp_path / "v1.sqlite"
    conn = sqlite3.connect(path)
    conn.executescript("""
        CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
        INSERT INTO meta VALUES ('schema_version', '1');
        CREATE TABLE calibration (key TEXT PRIMARY KEY, step_m REAL NOT NULL,
            variance_m2 REAL NOT NULL, steps INTEGER NOT NULL, updated_s REAL NOT NULL);
        INSERT INTO calibration VALUES ('k', 3e-6, 1e-15, 40, 5.0);
    """)
    conn.commit()
    conn.close()
    store = Store(path)
    assert store.calibration("k") == Calibration("k", 3e-6, 1e-15, 40, 5.0, 0.0, 0.25 * 3e-6 * 3e-6, 0.0)
    store.close()
    version = (
        sqlite3.connect(path).execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0]
    )
    assert version == str(SCHEMA_VERSION)


def test_a_version_3_database_gains_poses_and_pose_moves_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "v3.sqlite"
    Store(path).close()
    conn = sqlite3.connect(path)  # back to version 3: no pose columns
    conn.executescript("""
        ALTER TABLE moves DROP COLUMN part; ALTER TABLE moves DROP COLUMN target_pose;
        ALTER TABLE moves DROP COLUMN start_pose; ALTER TABLE moves DROP COLUMN reached_pose;
        ALTER TABLE moves DROP COLUMN error_rad; ALTER TABLE position DROP COLUMN poses;
        UPDATE meta SET value = '3' WHERE key = 'schema_version';
    """)
    conn.close()
    store = Store(path)
    move = store.begin_move(1e-3, 0.0, part=2, target_pose=(1e-3, -2e-4, 0.5), start_pose=(0.0, 0.0, 0.1))
    store.finish_move(
        move,
        status="done",
        reason="within tolerance",
        reached_m=1.0004e-3,
        steps=30,
        bursts=4,
        step_forward_m=None,
        step_backward_m=None,
        reached_pose=(1.0004e-3, -2.003e-4, 0.5005),
        error_m=5e-7,
        error_rad=5e-4,
    )
    store.save_position(1.0004e-3, ((1.0004e-3, -2.003e-4, 0.5005), (0.0, 1e-3, 0.0)))
    row = store.move(move)
    assert row is not None
    assert row["part"] == 2 and row["target_pose"] == [1e-3, -2e-4, 0.5]
    assert row["start_pose"] == [0.0, 0.0, 0.1] and row["reached_pose"] == [1.0004e-3, -2.003e-4, 0.5005]
    assert (row["error_m"], row["error_rad"]) == (5e-7, 5e-4)  # the distance, not reached − target in x
    known = store.position()
    assert known is not None and known.poses[1] == (0.0, 1e-3, 0.0)
    store.save_pose_response({"x/forward/coarse": {"step_m": 1e-6}})
    assert store.pose_response() == {"x/forward/coarse": {"step_m": 1e-6}}
    store.close()


def test_a_version_2_database_gains_the_steps_estimated_mark(tmp_path: Path) -> None:
    path = tmp_path / "v2.sqlite"
    store = Store(path)
    move = store.begin_move(1e-4, 0.0)
    store.close()
    conn = sqlite3.connect(path)  # back to version 2: the column did not exist
    conn.executescript("""
        ALTER TABLE moves DROP COLUMN steps_estimated;
        UPDATE meta SET value = '2' WHERE key = 'schema_version';
    """)
    conn.close()
    store = Store(path)
    store.finish_move(
        move,
        status="stopped",
        reason="stop",
        reached_m=5e-5,
        steps=12,
        bursts=1,
        step_forward_m=None,
        step_backward_m=None,
        steps_estimated=True,
    )
    assert store.moves()[0]["steps_estimated"] is True and store.moves()[0]["steps"] == 12
    store.close()


def test_a_stored_step_that_is_not_a_number_is_learned_again(tmp_path: Path) -> None:
    """A database written before readings were checked may hold an infinite step (a 1e308 m
    reading): it is not restored (it failed every later move), the finite ones are."""
    store = Store(tmp_path / "state.sqlite")
    store.save_calibration(Calibration("k/coarse/forward", float("inf"), 1e-12, 40, time.time()))
    store.save_calibration(Calibration("k/coarse/backward", 3.1e-6, 1e-14, 40, time.time()))
    restored = MoveRecords(store, "k", pose_control=False).restored_estimates()
    store.close()
    assert set(restored) == {"coarse/backward"}
    assert restored["coarse/backward"].step_m == 3.1e-6
