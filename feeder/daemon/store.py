"""The daemon's persistent state in SQLite: calibration, move history, last known position.

WAL journal, ``synchronous=FULL``, every change in one transaction: a process
killed with SIGKILL (or a power cut) leaves the database at its last committed
transaction.  One connection guarded by a lock, so the control loop and the
socket threads can share a :class:`Store`.

The file the store opened must stay the one at its path: each write first checks
that the path still names it (its device and inode; one ``stat``).  A database removed,
moved away or replaced while open is written no more (:class:`StoreError`): what the
store held is saved beside it (:func:`copy_database`), and its WAL is emptied into the
file it has open, so neither a replacement nor a new database at that path ever takes in
the old one's WAL.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import sqlite3
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from feeder.daemon.state_files import StoreError, check_state_file, copy_database, file_id, free_name
from feeder.daemon.store_schema import (
    ADDED_IN_4,
    CALIBRATION_COLUMNS,
    MIGRATE_1_TO_2,
    MIGRATE_2_TO_3,
    MOVE_COLUMNS,
    POSE_COLUMNS,
    SCHEMA,
    SCHEMA_VERSION,
)
from feeder.pose import Pose

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Calibration:
    """One learned step: step and burst offset (m), their covariance (m²), steps observed."""

    key: str
    step_m: float
    variance_m2: float
    steps: int
    updated_s: float
    offset_m: float = 0.0
    offset_variance_m2: float = 0.0
    covariance_m2: float = 0.0


@dataclass(frozen=True)
class KnownPosition:
    """The last position the sensor confirmed (m) and when (Unix time, s); every part's pose
    when the sensor sees poses."""

    position_m: float
    updated_s: float
    poses: tuple[Pose, ...] = ()


class Store:
    """The state database at ``path`` (created with its parent directory, mode 0700)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._file_id: tuple[int, int] | None = None  # the open file's (st_dev, st_ino)
        self._lost: str | None = None  # why writes are refused: the path names another file, or none
        self._closed = False
        existed = self.path.exists()
        if existed:
            check_state_file(self.path)
        else:  # owner-only from the start: SQLite gives its WAL and SHM files the database's mode
            os.close(os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        try:
            self._conn = sqlite3.connect(
                str(self.path), timeout=10.0, isolation_level=None, check_same_thread=False
            )
            self._file_id = file_id(self.path)
            if self._file_id is None:
                raise StoreError(f"{self.path}: removed while it was being opened")
            ok = self._conn.execute("PRAGMA quick_check").fetchone()[0]
            if ok != "ok":
                raise StoreError(f"{self.path}: integrity check failed: {ok}")
            if existed and self._foreign():
                raise StoreError(
                    f"{self.path}: not a feeder state database (no schema "
                    "version); refusing to touch it (feeder daemon --reset-state "
                    "moves it aside)"
                )
            self._conn.execute("PRAGMA journal_mode=WAL")  # writes the header: ours only
            self._conn.execute("PRAGMA synchronous=FULL")
            self._conn.executescript("BEGIN IMMEDIATE;" + SCHEMA + "COMMIT;")
            version = self._meta("schema_version")
            if version is not None and not version.isdigit():
                raise StoreError(
                    f"{self.path}: schema version {version!r} is not a number; not a feeder state database"
                )
            if version is None:
                self._set_meta("schema_version", str(SCHEMA_VERSION))
            elif int(version) > SCHEMA_VERSION:
                raise StoreError(f"{self.path}: schema version {version} is newer than this feeder")
            else:
                if int(version) == 1:
                    self._conn.executescript(MIGRATE_1_TO_2)
                if int(version) <= 2:
                    columns = {r[1] for r in self._conn.execute("PRAGMA table_info(moves)")}
                    alter = (
                        ""
                        if "steps_estimated" in columns
                        else "ALTER TABLE moves ADD COLUMN steps_estimated INTEGER NOT NULL DEFAULT 0;"
                    )
                    self._conn.executescript(MIGRATE_2_TO_3.format(alter=alter))
                if int(version) <= 3:
                    self._migrate_to_4()
            self._check_columns()
        except sqlite3.DatabaseError as err:
            raise StoreError(f"{self.path}: {err}") from err
        except OSError as err:  # the file gone between its creation and its stat
            raise StoreError(f"{self.path}: {err.strerror or err}") from None
        try:
            for path in (self.path, *(self.path.with_name(self.path.name + s) for s in ("-wal", "-shm"))):
                with contextlib.suppress(FileNotFoundError):
                    path.chmod(0o600)  # an older file's WAL, made with its mode
        except OSError as err:
            raise StoreError(f"{self.path}: {err.strerror or err}") from None

    def _migrate_to_4(self) -> None:
        with self._conn:
            self._conn.execute("BEGIN IMMEDIATE")
            for table, column, kind in ADDED_IN_4:
                columns = {r[1] for r in self._conn.execute(f"PRAGMA table_info({table})")}
                if column not in columns:
                    self._conn.execute(f"ALTER TABLE {table} ADD COLUMN {column} {kind}")
            self._conn.execute("UPDATE meta SET value = '4' WHERE key = 'schema_version'")

    def _check_columns(self) -> None:
        """Every table has the columns this schema uses (a file that says it is schema
        :data:`SCHEMA_VERSION` but lacks them failed later, mid-start, with a traceback)."""
        probe = sqlite3.connect(":memory:")
        try:
            probe.executescript(SCHEMA)
            for (table,) in probe.execute("SELECT name FROM sqlite_master WHERE type = 'table'").fetchall():
                wanted = {r[1] for r in probe.execute(f"PRAGMA table_info({table})")}
                have = {r[1] for r in self._conn.execute(f"PRAGMA table_info({table})")}
                if wanted - have:
                    missing = ", ".join(sorted(wanted - have))
                    raise StoreError(f"{self.path}: table {table} lacks {missing}; not this feeder's schema")
        finally:
            probe.close()

    def _foreign(self) -> bool:
        """Tables, but no feeder schema version among them: another program's database."""
        tables = {r[0] for r in self._conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if not tables:
            return False  # a fresh, empty database: ours to set up
        if "meta" not in tables:
            return True
        return self._conn.execute("SELECT count(*) FROM meta WHERE key = 'schema_version'").fetchone()[0] == 0

    # -- plumbing ---------------------------------------------------------
    def _write(self, sql: str, params: tuple[Any, ...] = ()) -> sqlite3.Cursor:
        """One statement in its own IMMEDIATE transaction (the file checked first)."""
        with self._lock:
            self._check_file()
            with self._conn:  # COMMIT on success, ROLLBACK on any error
                self._conn.execute("BEGIN IMMEDIATE")
                return self._conn.execute(sql, params)

    def _write_all(self, statements: Sequence[tuple[str, tuple[Any, ...]]]) -> None:
        """Several statements in one IMMEDIATE transaction: all of them or none."""
        with self._lock:
            self._check_file()
            with self._conn:
                self._conn.execute("BEGIN IMMEDIATE")
                for sql, params in statements:
                    self._conn.execute(sql, params)

    def _check_file(self) -> None:
        """Raise :class:`StoreError` unless :attr:`path` still names the file this store has
        open (caller holds the lock).  The first time it does not, what the store holds is
        saved beside it and its WAL emptied into its own file (:meth:`_set_aside`)."""
        if self._file_id is None:  # still opening: the file is the one just opened
            return
        try:
            now = file_id(self.path)
        except OSError as err:  # the folder unreadable: cannot tell, do not write
            raise StoreError(f"{self.path}: {err.strerror or err}") from None
        if now == self._file_id:
            self._lost = None  # moved back: the same file again
            return
        if self._lost is None:
            self._lost = self._set_aside(replaced=now is not None)
        raise StoreError(self._lost)

    def _set_aside(self, replaced: bool) -> str:
        """The database at :attr:`path` is gone or another: save what the store holds to
        ``NAME.TIMESTAMP.bak`` beside it, empty the store's WAL into the file it has open (never
        the new one: a WAL left at the path would be applied to whatever is there at its next
        open), and return the reason writes are refused."""
        what = "replaced by another file" if replaced else "removed or moved away"
        try:
            saved = free_name(self.path.with_name(f"{self.path.name}.{time.strftime('%Y%m%dT%H%M%S')}.bak"))
            copy_database(self._conn, saved, check=False)  # all there is
            kept = f"what it held is saved beside it as {saved.name}"
        except (OSError, sqlite3.Error) as err:
            kept = f"what it held could not be saved beside it: {err}"
        self._empty_wal()
        reason = (
            f"{self.path}: the state database was {what} while the daemon had it open; "
            f"not written any more ({kept}); restart the daemon to "
            + ("use the new file" if replaced else "start a new one")
        )
        log.error("%s", reason)
        return reason

    def _empty_wal(self) -> None:
        """Checkpoint the WAL into the file this connection has open and truncate it."""
        try:
            busy, frames, done = self._conn.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()
        except sqlite3.Error as err:
            log.error("%s: the WAL could not be emptied into the file open here: %s", self.path, err)
            return
        if busy or frames != done:
            log.error("%s: the WAL could not be emptied (a reader holds it): %d of %d frames", self.path,
                      done, frames)  # fmt: skip

    def _read(self, sql: str, params: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
        with self._lock:
            return self._conn.execute(sql, params).fetchall()

    def _meta(self, key: str) -> str | None:
        rows = self._read("SELECT value FROM meta WHERE key = ?", (key,))
        return str(rows[0][0]) if rows else None

    def _set_meta(self, key: str, value: str) -> None:
        self._write("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)", (key, value))

    def close(self) -> None:
        """Close the database.  Should its file have been removed or replaced meanwhile, what the
        store held is saved beside it first and its WAL emptied into its own file
        (:meth:`_check_file`): nothing is left for a new file at the path to take in."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            with contextlib.suppress(StoreError):  # logged where it is found
                self._check_file()
            self._conn.close()

    def integrity_ok(self) -> bool:
        """Full ``PRAGMA integrity_check``."""
        return self._read("PRAGMA integrity_check")[0][0] == "ok"

    # -- calibration ------------------------------------------------------
    def save_calibration(self, cal: Calibration) -> None:
        self._write(*_calibration_row(cal))

    def calibration(self, key: str) -> Calibration | None:
        rows = self._read(f"SELECT {CALIBRATION_COLUMNS} FROM calibration WHERE key = ?", (key,))
        return Calibration(*rows[0]) if rows else None

    # -- moves ------------------------------------------------------------
    def begin_move(
        self,
        target_m: float,
        start_m: float | None,
        *,
        part: int | None = None,
        target_pose: Pose | None = None,
        start_pose: Pose | None = None,
    ) -> int:
        """Record a move as ``running`` (a pose move with its part and poses); returns its id."""
        cur = self._write(
            "INSERT INTO moves (started_s, start_m, target_m, status, part, target_pose, start_pose)"
            " VALUES (?, ?, ?, 'running', ?, ?, ?)",
            (time.time(), start_m, target_m, part, _pose_json(target_pose), _pose_json(start_pose)),
        )
        return int(cur.lastrowid or 0)

    def finish_move(
        self,
        move_id: int,
        *,
        status: str,
        reason: str,
        reached_m: float | None,
        steps: int,
        bursts: int,
        step_forward_m: float | None,
        step_backward_m: float | None,
        steps_estimated: bool = False,
        reached_pose: Pose | None = None,
        error_m: float | None = None,
        error_rad: float | None = None,
    ) -> None:
        """Close a move: status ``done``/``stopped``/``stalled``/``limit``/``fault``.  A pose
        move gives its reached pose and errors (distance, angle); else the error is along x."""
        error = error_m
        if reached_pose is None:
            rows = self._read("SELECT target_m FROM moves WHERE id = ?", (move_id,))
            error = None if reached_m is None or not rows else reached_m - float(rows[0][0])
        self._write(
            "UPDATE moves SET finished_s = ?, reached_m = ?, error_m = ?, steps = ?, bursts = ?,"
            " status = ?, reason = ?, step_forward_m = ?, step_backward_m = ?, steps_estimated = ?,"
            " reached_pose = ?, error_rad = ? WHERE id = ?",
            (
                time.time(),
                reached_m,
                error,
                steps,
                bursts,
                status,
                reason,
                step_forward_m,
                step_backward_m,
                int(steps_estimated),
                _pose_json(reached_pose),
                error_rad,
                move_id,
            ),
        )

    def progress_move(self, move_id: int, *, steps: int, bursts: int) -> None:
        """A running move's steps and bursts commanded so far."""
        self.save_progress(move_id, steps=steps, bursts=bursts)

    def save_progress(
        self,
        move_id: int | None,
        *,
        steps: int,
        bursts: int,
        calibrations: Sequence[Calibration] = (),
        pose_response: dict[str, Any] | None = None,
    ) -> None:
        """In one transaction: a running move's steps and bursts so far (``move_id`` None: no
        move record, e.g. a calibration) and what was learned so far, so that a daemon killed
        mid-move keeps both.  ``pose_response`` with a value that is not a finite number is a
        ValueError, before anything is written."""
        statements: list[tuple[str, tuple[Any, ...]]] = []
        if move_id is not None:
            statements.append(("UPDATE moves SET steps = ?, bursts = ? WHERE id = ? AND status = 'running'",
                               (steps, bursts, move_id)))  # fmt: skip
        statements += [_calibration_row(cal) for cal in calibrations]
        if pose_response is not None:
            statements.append(_pose_response_row(pose_response))
        if statements:
            self._write_all(statements)

    def interrupt_running_moves(self) -> list[int]:
        """Mark moves left ``running`` by a killed daemon as ``interrupted``; their ids."""
        with self._lock:
            self._check_file()
            self._conn.execute("BEGIN IMMEDIATE")
            ids = [
                int(r[0])
                for r in self._conn.execute("SELECT id FROM moves WHERE status = 'running' ORDER BY id")
            ]
            self._conn.execute(
                "UPDATE moves SET status = 'interrupted',"
                " reason = 'daemon stopped during the move (crash or kill); steps: as commanded'"
                " WHERE status = 'running'"
            )
            self._conn.execute("COMMIT")
        return ids

    def moves(self, limit: int = 100) -> list[dict[str, Any]]:
        """The newest ``limit`` moves, oldest first."""
        rows = self._read(f"SELECT {', '.join(MOVE_COLUMNS)} FROM moves ORDER BY id DESC LIMIT ?", (limit,))
        return [_move_row(row) for row in reversed(rows)]

    def move(self, move_id: int) -> dict[str, Any] | None:
        rows = self._read(f"SELECT {', '.join(MOVE_COLUMNS)} FROM moves WHERE id = ?", (move_id,))
        return _move_row(rows[0]) if rows else None

    # -- position ---------------------------------------------------------
    def save_position(self, position_m: float, poses: tuple[Pose, ...] = ()) -> None:
        """The part's x (m) and, from a pose sensor, every part's pose."""
        self._write(
            "INSERT OR REPLACE INTO position (id, position_m, updated_s, poses) VALUES (1, ?, ?, ?)",
            (position_m, time.time(), json.dumps([list(p) for p in poses]) if poses else None),
        )

    def position(self) -> KnownPosition | None:
        rows = self._read("SELECT position_m, updated_s, poses FROM position WHERE id = 1")
        if not rows:
            return None
        poses = tuple(tuple(p) for p in json.loads(rows[0][2])) if rows[0][2] else ()
        return KnownPosition(rows[0][0], rows[0][1], poses)

    # -- the pose planner's learned response ---------------------------------
    def save_pose_response(self, estimates: dict[str, Any]) -> None:
        self._write(*_pose_response_row(estimates))

    def pose_response(self) -> dict[str, Any] | None:
        rows = self._read("SELECT estimates FROM pose_response WHERE id = 1")
        return json.loads(rows[0][0]) if rows else None

    # -- camera calibration (feeder vision calibrate --save-state) ------------
    def save_camera_calibration(self, calibration: dict[str, Any]) -> None:
        """The camera-to-plate transform (pixel size, rotation, θ centre), stored beside the
        step calibration."""
        self._write(
            "INSERT OR REPLACE INTO camera_calibration (id, calibration, updated_s) VALUES (1, ?, ?)",
            (json.dumps(calibration, allow_nan=False), time.time()),
        )

    def camera_calibration(self) -> dict[str, Any] | None:
        rows = self._read("SELECT calibration, updated_s FROM camera_calibration WHERE id = 1")
        if not rows:
            return None
        return {**json.loads(rows[0][0]), "updated_s": rows[0][1]}


def _calibration_row(cal: Calibration) -> tuple[str, tuple[Any, ...]]:
    return (
        f"INSERT OR REPLACE INTO calibration ({CALIBRATION_COLUMNS}) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
        (
            cal.key,
            cal.step_m,
            cal.variance_m2,
            cal.steps,
            cal.updated_s,
            cal.offset_m,
            cal.offset_variance_m2,
            cal.covariance_m2,
        ),
    )


def _pose_response_row(estimates: dict[str, Any]) -> tuple[str, tuple[Any, ...]]:
    return (
        "INSERT OR REPLACE INTO pose_response (id, estimates, updated_s) VALUES (1, ?, ?)",
        (json.dumps(estimates, allow_nan=False), time.time()),
    )


def _pose_json(pose: Pose | None) -> str | None:
    """[x, y, angle] as JSON; a NaN angle (any angle) as null."""
    if pose is None:
        return None
    return json.dumps([None if math.isnan(v) else v for v in pose], allow_nan=False)


def _move_row(row: tuple[Any, ...]) -> dict[str, Any]:
    out = dict(zip(MOVE_COLUMNS, row, strict=True))
    out["steps_estimated"] = bool(out["steps_estimated"])
    for key in POSE_COLUMNS:
        out[key] = None if out[key] is None else json.loads(out[key])
    return out
