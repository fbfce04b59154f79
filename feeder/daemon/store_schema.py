"""The state database's schema as data: its tables, its version and the steps from each
earlier version, and the column lists the store reads and writes (:mod:`feeder.daemon.store`)."""

from __future__ import annotations

SCHEMA_VERSION = 4

SCHEMA = """
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

MIGRATE_1_TO_2 = """
BEGIN IMMEDIATE;
ALTER TABLE calibration ADD COLUMN offset_m REAL NOT NULL DEFAULT 0;
ALTER TABLE calibration ADD COLUMN offset_variance_m2 REAL NOT NULL DEFAULT 0;
ALTER TABLE calibration ADD COLUMN covariance_m2 REAL NOT NULL DEFAULT 0;
UPDATE calibration SET offset_variance_m2 = 0.25 * step_m * step_m;
UPDATE meta SET value = '2' WHERE key = 'schema_version';
COMMIT;
"""
"""Version 2 learns a per-burst offset beside the step; old rows get the seed's offset prior."""

MIGRATE_2_TO_3 = """
BEGIN IMMEDIATE;
{alter}
UPDATE meta SET value = '3' WHERE key = 'schema_version';
COMMIT;
"""
"""Version 3 marks moves whose step count was estimated from time (a stop cut a burst on a
drive that counts no steps, e.g. the ANC300)."""

ADDED_IN_4 = (
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
POSE_COLUMNS = ("target_pose", "start_pose", "reached_pose")
