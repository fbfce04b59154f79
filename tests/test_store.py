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

from feeder.daemon.jobs import Job
from feeder.daemon.move_records import MoveRecords
from feeder.daemon.step_estimator import StepEstimate
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


def stored_targets(path: Path) -> list[float]:
    """The moves' targets in the database at ``path``, read as a new daemon would find them."""
    store = Store(path)
    try:
        return [m["target_m"] for m in store.moves()]
    finally:
        store.close()


def _saved_beside(path: Path) -> list[Path]:
    return sorted(path.parent.glob(f"{path.name}.*.bak"))


def test_a_database_removed_while_open_is_written_no_more(tmp_path: Path) -> None:
    """The old store went on writing into the unlinked file (and left its WAL at the path, for a
    new database there to take in); every write now refuses, naming the file, and what the store
    held is saved beside it."""
    path = tmp_path / "state" / "feeder.sqlite"
    store = Store(path)
    for i in range(3):
        store.begin_move(i * 1e-6, 0.0)
    path.unlink()
    with pytest.raises(StoreError, match=r"feeder\.sqlite: the state database was removed or moved away"):
        store.begin_move(9e-6, 0.0)
    with pytest.raises(StoreError, match="removed"):  # and every write after it
        store.save_position(1e-6)
    store.close()
    assert not path.exists()  # not re-created: a new daemon starts a new one
    (saved,) = _saved_beside(path)
    assert oct(saved.stat().st_mode & 0o777) == "0o600"
    assert stored_targets(saved) == [0.0, 1e-6, 2e-6]  # everything the store held, nothing else
    wal = path.with_name(path.name + "-wal")
    assert not wal.exists() or wal.stat().st_size == 0  # nothing for a new database to take in
    assert stored_targets(path) == []  # the next start: a fresh database


def _replaced_under_a_store(path: Path, target_m: float) -> Store:
    """A store at ``path`` with three moves (targets 0, 1 and 2 µm), its file then replaced by
    another database holding one move to ``target_m``; the store, still open."""
    store = Store(path)
    for i in range(3):
        store.begin_move(i * 1e-6, 0.0)
    other = path.with_name("other.sqlite")
    replacement = Store(other)
    replacement.begin_move(target_m, 0.0)
    replacement.close()
    os.replace(other, path)
    return store


def test_a_database_replaced_while_open_is_never_written_into(tmp_path: Path) -> None:
    """The old store's WAL, left at the path, was applied to the replacement when it was next
    opened: the replacement then held the old database's moves instead of its own."""
    path = tmp_path / "state" / "feeder.sqlite"
    store = _replaced_under_a_store(path, 99e-6)
    with pytest.raises(StoreError, match=r"feeder\.sqlite: the state database was replaced by another file"):
        store.save_position(1e-6)
    store.close()
    assert stored_targets(path) == [99e-6]
    (saved,) = _saved_beside(path)
    assert stored_targets(saved) == [0.0, 1e-6, 2e-6]


def test_a_database_replaced_before_the_store_closes_keeps_its_own_contents(tmp_path: Path) -> None:
    """No write in between: closing the store (a daemon's shutdown) left its WAL at the path, and
    the replacement's next opening took it in."""
    path = tmp_path / "feeder.sqlite"
    store = _replaced_under_a_store(path, 42e-6)
    store.close()
    assert stored_targets(path) == [42e-6]
    (saved,) = _saved_beside(path)
    assert stored_targets(saved) == [0.0, 1e-6, 2e-6]


def test_a_database_moved_back_is_written_again(tmp_path: Path) -> None:
    path = tmp_path / "feeder.sqlite"
    store = Store(path)
    store.begin_move(1e-6, 0.0)
    path.rename(tmp_path / "elsewhere.sqlite")
    with pytest.raises(StoreError, match="removed or moved away"):
        store.save_position(1e-6)
    (tmp_path / "elsewhere.sqlite").rename(path)
    store.save_position(2e-6)  # the same file again: written
    store.close()
    kept = Store(path)
    position = kept.position()
    kept.close()
    assert position is not None and position.position_m == 2e-6


class _Loop:
    """What MoveRecords reads of the control loop: the position and what has been learned."""

    reading = None
    position_m = 0.0

    def __init__(self) -> None:
        self.learned: dict[str, StepEstimate] = {}
        self.response: dict[str, object] = {}

    def estimates(self) -> dict[str, StepEstimate]:
        return dict(self.learned)

    def estimates_json(self) -> dict[str, object]:
        return dict(self.response)


def test_steps_learned_during_a_move_outlive_the_daemon_killed_before_its_end(tmp_path: Path) -> None:
    """They were stored only at the move's end: a daemon killed mid-move lost them."""
    path = tmp_path / "feeder.sqlite"
    store = Store(path)
    records = MoveRecords(store, "k", pose_control=False)
    loop = _Loop()
    job = Job("move", target_m=800e-6)
    records.begin(job, loop)  # type: ignore[arg-type]
    loop.learned = {"coarse/forward": StepEstimate(3.05e-6, 4e-16, 60, 0.2e-6, 1e-15, -1e-16),
                    "coarse/backward": StepEstimate(2.6e-6, 1e-14, 0)}  # fmt: skip
    job.steps, job.bursts = 120, 2
    records.progress(job)  # the second burst commanded; then the daemon is killed
    store.close()

    again = Store(path)
    assert again.interrupt_running_moves() == [job.record_id]
    restored = MoveRecords(again, "k", pose_control=False).restored_estimates()
    (move,) = again.moves()
    again.close()
    assert set(restored) == {"coarse/forward"}  # a step never observed is not stored
    assert restored["coarse/forward"] == StepEstimate(3.05e-6, 4e-16, 60, 0.2e-6, 1e-15, -1e-16)
    assert (move["status"], move["steps"], move["bursts"]) == ("interrupted", 120, 2)


def test_the_response_learned_during_a_pose_move_outlives_the_daemon(tmp_path: Path) -> None:
    path = tmp_path / "feeder.sqlite"
    store = Store(path)
    records = MoveRecords(store, "k", pose_control=True)
    loop = _Loop()
    job = Job("calibrate")  # no move record: what it learns is kept all the same
    records.begin(job, loop)  # type: ignore[arg-type]
    loop.response = {"gains": {"x/+/coarse/step": {"gain": [3.1e-6], "bursts": 4}}}
    records.progress(job)
    loop.response = {"gains": {"x/+/coarse/step": {"gain": [float("nan")], "bursts": 5}}}
    records.progress(job)  # not a number: not stored, the last one stays
    store.close()
    again = Store(path)
    kept = MoveRecords(again, "k", pose_control=True).restored_pose_response()
    again.close()
    assert kept == {"key": "k", "gains": {"x/+/coarse/step": {"gain": [3.1e-6], "bursts": 4}}}
