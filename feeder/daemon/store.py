"""The daemon's persistent state in SQLite: calibration, move history, last known position.

WAL journal, ``synchronous=FULL``, every change in one transaction: a process
killed with SIGKILL (or a power cut) leaves the database at its last committed
transaction.  One connection guarded by a lock, so the control loop and the
socket threads can share a :class:`Store`.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from feeder.errors import FeederError
from feeder.pose import Pose

SCHEMA_VERSION = 4

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS calibration (
    key TEXT PRIMARY KEY,
    step_m REAL NOT NULL,
    variance_m2 REAL NOT NULL,
    steps INTEGER NOT NULL,
    updated_s REAL NOT NULL,
    offset_m REAL NOT NULL DEFAULT 0,
    offset_variance_m2 REAL NOT NULL DEFAULT 0,
    covariance_m2 REAL NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS moves (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    started_s REAL NOT NULL,
    finished_s REAL,
    start_m REAL,
    target_m REAL NOT NULL,
    reached_m REAL,
    error_m REAL,
    steps INTEGER NOT NULL DEFAULT 0,
    bursts INTEGER NOT NULL DEFAULT 0,
    status TEXT NOT NULL,
    reason TEXT NOT NULL DEFAULT '',
    step_forward_m REAL,
    step_backward_m REAL,
    steps_estimated INTEGER NOT NULL DEFAULT 0,
    part INTEGER,
    target_pose TEXT,
    start_pose TEXT,
    reached_pose TEXT,
    error_rad REAL
);
CREATE TABLE IF NOT EXISTS position (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    position_m REAL NOT NULL,
    updated_s REAL NOT NULL,
    poses TEXT
);
CREATE TABLE IF NOT EXISTS pose_response (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    estimates TEXT NOT NULL,
    updated_s REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS camera_calibration (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    calibration TEXT NOT NULL,
    updated_s REAL NOT NULL
);
"""

_MIGRATE_1_TO_2 = """
BEGIN IMMEDIATE;
ALTER TABLE calibration ADD COLUMN offset_m REAL NOT NULL DEFAULT 0;
ALTER TABLE calibration ADD COLUMN offset_variance_m2 REAL NOT NULL DEFAULT 0;
ALTER TABLE calibration ADD COLUMN covariance_m2 REAL NOT NULL DEFAULT 0;
UPDATE calibration SET offset_variance_m2 = 0.25 * step_m * step_m;
UPDATE meta SET value = '2' WHERE key = 'schema_version';
COMMIT;
"""
"""Version 2 learns a per-burst offset beside the step; old rows get the seed's offset prior."""

_MIGRATE_2_TO_3 = """
BEGIN IMMEDIATE;
{alter}
UPDATE meta SET value = '3' WHERE key = 'schema_version';
COMMIT;
"""
"""Version 3 marks moves whose step count was estimated from time (a stop cut a burst on a
drive that counts no steps, e.g. the ANC300)."""

_ADDED_IN_4 = (
    ("moves", "part", "INTEGER"),
    ("moves", "target_pose", "TEXT"),
    ("moves", "start_pose", "TEXT"),
    ("moves", "reached_pose", "TEXT"),
    ("moves", "error_rad", "REAL"),
    ("position", "poses", "TEXT"),
)
"""Version 4 records poses (x_m, y_m, psi_rad as JSON) beside the x positions, and the pose
planner's learned response (table ``pose_response``, created by the schema)."""

CALIBRATION_COLUMNS = (
    "key, step_m, variance_m2, steps, updated_s, offset_m, offset_variance_m2, covariance_m2"
)

MOVE_COLUMNS = (
    "id",
    "started_s",
    "finished_s",
    "start_m",
    "target_m",
    "reached_m",
    "error_m",
    "steps",
    "bursts",
    "status",
    "reason",
    "step_forward_m",
    "step_backward_m",
    "steps_estimated",
    "part",
    "target_pose",
    "start_pose",
    "reached_pose",
    "error_rad",
)
_POSE_COLUMNS = ("target_pose", "start_pose", "reached_pose")


class StoreError(FeederError, RuntimeError):
    """The state database is unusable (corrupt, newer schema, not a database)."""


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
        existed = self.path.exists()
        if existed:
            check_state_file(self.path)
        else:  # owner-only from the start: SQLite gives its WAL and SHM files the database's mode
            os.close(os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        try:
            self._conn = sqlite3.connect(
                str(self.path), timeout=10.0, isolation_level=None, check_same_thread=False
            )
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
            self._conn.executescript("BEGIN IMMEDIATE;" + _SCHEMA + "COMMIT;")
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
                    self._conn.executescript(_MIGRATE_1_TO_2)
                if int(version) <= 2:
                    columns = {r[1] for r in self._conn.execute("PRAGMA table_info(moves)")}
                    alter = (
                        ""
                        if "steps_estimated" in columns
                        else "ALTER TABLE moves ADD COLUMN steps_estimated INTEGER NOT NULL DEFAULT 0;"
                    )
                    self._conn.executescript(_MIGRATE_2_TO_3.format(alter=alter))
                if int(version) <= 3:
                    self._migrate_to_4()
            self._check_columns()
        except sqlite3.DatabaseError as err:
            raise StoreError(f"{self.path}: {err}") from err
        try:
            for path in (self.path, *(self.path.with_name(self.path.name + s) for s in ("-wal", "-shm"))):
                with contextlib.suppress(FileNotFoundError):
                    path.chmod(0o600)  # an older file's WAL, made with its mode
        except OSError as err:
            raise StoreError(f"{self.path}: {err.strerror or err}") from None

    def _migrate_to_4(self) -> None:
        with self._conn:
            self._conn.execute("BEGIN IMMEDIATE")
            for table, column, kind in _ADDED_IN_4:
                columns = {r[1] for r in self._conn.execute(f"PRAGMA table_info({table})")}
                if column not in columns:
                    self._conn.execute(f"ALTER TABLE {table} ADD COLUMN {column} {kind}")
            self._conn.execute("UPDATE meta SET value = '4' WHERE key = 'schema_version'")

    def _check_columns(self) -> None:
        """Every table has the columns this schema uses (a file that says it is schema
        :data:`SCHEMA_VERSION` but lacks them failed later, mid-start, with a traceback)."""
        probe = sqlite3.connect(":memory:")
        try:
            probe.executescript(_SCHEMA)
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
        """One statement in its own IMMEDIATE transaction."""
        with self._lock, self._conn:  # COMMIT on success, ROLLBACK on any error
            self._conn.execute("BEGIN IMMEDIATE")
            return self._conn.execute(sql, params)

    def _read(self, sql: str, params: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
        with self._lock:
            return self._conn.execute(sql, params).fetchall()

    def _meta(self, key: str) -> str | None:
        rows = self._read("SELECT value FROM meta WHERE key = ?", (key,))
        return str(rows[0][0]) if rows else None

    def _set_meta(self, key: str, value: str) -> None:
        self._write("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)", (key, value))

    def close(self) -> None:
        with self._lock:
            self._conn.close()

    def integrity_ok(self) -> bool:
        """Full ``PRAGMA integrity_check``."""
        return self._read("PRAGMA integrity_check")[0][0] == "ok"

    # -- calibration ------------------------------------------------------
    def save_calibration(self, cal: Calibration) -> None:
        self._write(
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
        self._write("UPDATE moves SET steps = ?, bursts = ? WHERE id = ? AND status = 'running'",
                    (steps, bursts, move_id))  # fmt: skip

    def interrupt_running_moves(self) -> list[int]:
        """Mark moves left ``running`` by a killed daemon as ``interrupted``; their ids."""
        with self._lock:
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
        self._write(
            "INSERT OR REPLACE INTO pose_response (id, estimates, updated_s) VALUES (1, ?, ?)",
            (json.dumps(estimates, allow_nan=False), time.time()),
        )

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


def _pose_json(pose: Pose | None) -> str | None:
    """[x, y, angle] as JSON; a NaN angle (any angle) as null."""
    if pose is None:
        return None
    return json.dumps([None if math.isnan(v) else v for v in pose], allow_nan=False)


def _move_row(row: tuple[Any, ...]) -> dict[str, Any]:
    out = dict(zip(MOVE_COLUMNS, row, strict=True))
    out["steps_estimated"] = bool(out["steps_estimated"])
    for key in _POSE_COLUMNS:
        out[key] = None if out[key] is None else json.loads(out[key])
    return out


SQLITE_HEADER = b"SQLite format 3\x00"


def check_state_file(path: Path) -> None:
    """Refuse a state file that is not an SQLite database (empty, truncated, foreign), with
    :class:`StoreError` naming it; the file is left untouched."""
    try:
        with open(path, "rb") as handle:
            header = handle.read(100)
    except OSError as err:
        raise StoreError(f"{path}: cannot read: {err}") from None
    if not header:
        raise StoreError(
            f"{path}: empty file (a truncated state database?); refusing to start "
            "(feeder daemon --reset-state moves it aside)"
        )
    if not header.startswith(SQLITE_HEADER) or len(header) < 100:
        raise StoreError(
            f"{path}: not an SQLite database; refusing to start (feeder daemon --reset-state moves it aside)"
        )


def move_aside(path: Path) -> Path | None:
    """Rename the state database (and its WAL/SHM files) to ``NAME.YYYYmmddTHHMMSS.bak``;
    returns the new name, or None when there was nothing to move."""
    if not path.exists():
        return None
    stamp = time.strftime("%Y%m%dT%H%M%S")
    target = path.with_name(f"{path.name}.{stamp}.bak")
    for suffix in ("-wal", "-shm"):
        side = path.with_name(path.name + suffix)
        if side.exists():
            side.replace(target.with_name(target.name + suffix))
    path.replace(target)
    return target
