"""``feeder state backup|restore``: the daemon's state database (learned steps, move history,
last position, camera calibration) copied out safely while the daemon runs, and put back while
it does not.

A plain ``cp`` of ``feeder.sqlite`` under a running daemon copies the file without its WAL
(``feeder.sqlite-wal``), which holds the changes since SQLite last moved them into the file:
most of a day's history.  ``backup`` uses SQLite's online backup instead (a consistent copy,
WAL included, while the daemon writes on) and writes one self-contained file.  ``restore``
takes the state directory's lock (refused while a daemon uses it), checks the file the way the
daemon does at its start, and swaps it in; the database it replaces is moved aside, as
``feeder daemon --reset-state`` does.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import sqlite3
import stat
import tempfile
from pathlib import Path
from typing import Any

from feeder.cli.output import print_json
from feeder.daemon.state_files import StoreError, check_state_file, copy_database, fsync_path, move_aside
from feeder.errors import InputError

HELP = "back up the daemon's state database (safe while it runs), or restore one"

_DAEMON_HINT = re.compile(r"; refusing to (start|touch it) \(feeder daemon --reset-state moves it aside\)$")
"""The part of a state-file refusal that speaks to ``feeder daemon``, not to these commands."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("state", help=HELP)
    commands = parser.add_subparsers(
        dest="state_command", metavar="{backup,restore}", required=True, parser_class=type(parser)
    )
    backup = commands.add_parser(
        "backup",
        help="copy the state database to DEST, consistently, also while the daemon runs",
        description="Copy the daemon's state database (with what is still in its WAL) to DEST: one "
        "self-contained SQLite file, owner-only, written to a temporary file beside DEST and "
        "renamed. Safe while the daemon runs; nothing in the state directory is changed.",
    )
    backup.add_argument("dest", type=Path, metavar="DEST", help="the backup file to write")
    backup.add_argument("--force", action="store_true", help="replace DEST if it exists")
    _add_state_options(backup)
    backup.set_defaults(handler=run_backup)
    restore = commands.add_parser(
        "restore",
        help="replace the state database by SRC (a backup); the daemon must be stopped",
        description="Check SRC as the daemon checks its database at start (SQLite, integrity, a "
        "feeder schema no newer than this feeder's) and make it the state database. The one it "
        "replaces is moved aside to NAME.TIMESTAMP.bak. Refused while a daemon uses the state "
        "directory: stop it first (feeder shutdown).",
    )
    restore.add_argument("src", type=Path, metavar="SRC", help="the backup to restore")
    _add_state_options(restore)
    restore.set_defaults(handler=run_restore)


def _add_state_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--state-dir",
        type=Path,
        help="the daemon's state directory (default: the config's, else its default)",
    )
    parser.add_argument("--config", type=Path, help="the daemon's TOML, for its [state] dir")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def state_database(args: argparse.Namespace) -> Path:
    """The database the daemon started with the same ``--config`` and ``--state-dir`` uses."""
    from feeder.daemon.config_file import load_config

    return load_config(args.config).with_state_dir(args.state_dir).database_path


# -- backup ---------------------------------------------------------------------------------
def run_backup(args: argparse.Namespace) -> int:
    database = state_database(args)
    dest: Path = args.dest
    _check_backup_target(dest, database, args.force)
    source = _open_read_only(database, static=False)  # the daemon may be writing it
    try:
        _summary(source, database)  # a feeder state database: refused before DEST is touched
        try:
            copy_database(source, dest, overwrite=args.force)
        except FileExistsError:
            raise InputError(str(dest), "exists; --force replaces it") from None
        except StoreError as err:
            raise InputError(str(database), _detail(err, dest)) from None
        except sqlite3.OperationalError as err:  # writing the copy: disk full, I/O error
            raise InputError(str(dest), f"not written: {err}") from None
        except sqlite3.Error as err:  # reading the database: a damaged page
            raise InputError(str(database), f"cannot be copied: {err}; nothing written") from None
        except OSError as err:
            raise InputError(str(dest), f"cannot write: {err.strerror or err}") from None
    finally:
        source.close()
    copy = _open_read_only(dest, static=True)
    try:
        summary = {**_summary(copy, dest), **_file_summary(dest)}  # what the copy holds
    finally:
        copy.close()
    out = {"backup": str(dest), "database": str(database), **summary}
    if args.json:
        print_json(out)
    else:
        print(
            f"backed up {database} to {dest} (moves {summary['moves']}, learned steps "
            f"{summary['calibrations']}, {summary['size_bytes']} bytes)"
        )
    return 0


def _check_backup_target(dest: Path, database: Path, force: bool) -> None:
    """Refuse, before anything is read or written, a DEST that is a folder, in a missing folder,
    one of the state database's own files, or (without ``force``) an existing file."""
    if not dest.name or dest.is_dir():
        raise InputError(str(dest), "is a directory: name the backup file")
    if not dest.parent.is_dir():
        raise InputError(str(dest), f"no such directory: {dest.parent}")
    own = [database.with_name(database.name + suffix) for suffix in ("", "-wal", "-shm", ".lock")]
    if any(_same(dest, path) for path in own):
        raise InputError(str(dest), "is one of the state database's own files")
    try:
        info = dest.lstat()
    except FileNotFoundError:
        return
    except OSError as err:
        raise InputError(str(dest), f"cannot write: {err.strerror or err}") from None
    if not force:
        raise InputError(str(dest), "exists; --force replaces it")
    if not (stat.S_ISREG(info.st_mode) or stat.S_ISLNK(info.st_mode)):
        raise InputError(str(dest), "exists and is not a regular file")


def _same(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and a.samefile(b))
    except OSError:
        return False


# -- restore --------------------------------------------------------------------------------
def run_restore(args: argparse.Namespace) -> int:
    database = state_database(args)
    src: Path = args.src
    _check_restore_source(src, database)
    from feeder.daemon.service import lock_state  # loads the daemon's modules: after the checks

    try:
        lock = lock_state(database)
    except InputError:
        raise InputError(
            str(database.parent),
            "a daemon is using this state directory: stop it first (feeder shutdown), then restore",
        ) from None
    except OSError as err:
        raise InputError(str(database.parent), f"cannot use: {err.strerror or err}") from None
    try:
        prepared, summary = _prepare(src, database)
        previous = None
        try:
            previous = move_aside(database)
            os.replace(prepared, database)
            fsync_path(database.parent)
        except OSError as err:
            kept = "" if previous is None else f"; the database it was to replace is {previous}"
            raise InputError(str(database), f"not restored: {err.strerror or err}{kept}") from None
        finally:
            _remove(prepared)
    finally:
        lock.close()
    out = {
        "restored": str(database),
        "from": str(src),
        "previous": None if previous is None else str(previous),
        **summary,
        **_file_summary(database),
    }
    if args.json:
        print_json(out)
    else:
        kept = "there was none" if previous is None else f"the one it replaced is {previous}"
        print(
            f"restored {database} from {src} (moves {summary['moves']}, learned steps "
            f"{summary['calibrations']}); {kept}"
        )
    return 0


def _check_restore_source(src: Path, database: Path) -> None:
    try:
        info = src.stat()
    except FileNotFoundError:
        raise InputError(str(src), "no such file") from None
    except OSError as err:
        raise InputError(str(src), f"cannot read: {err.strerror or err}") from None
    if not stat.S_ISREG(info.st_mode):
        raise InputError(str(src), "not a regular file")
    if _same(src, database):
        raise InputError(str(src), "is the state database itself")
    try:
        check_state_file(src)
    except StoreError as err:
        raise InputError(str(src), _detail(err, src)) from None


def _prepare(src: Path, database: Path) -> tuple[Path, dict[str, Any]]:
    """SRC copied into the state directory (a temporary name) and opened as the daemon opens
    its database (integrity, schema; an older schema migrated); the copy and its summary.  Any
    refusal is an InputError naming SRC, and leaves no file behind."""
    from feeder.daemon.store import Store

    handle, name = tempfile.mkstemp(dir=database.parent, prefix=f".{database.name}.restore.", suffix=".tmp")
    os.close(handle)
    prepared = Path(name)
    ready = False
    try:
        source = _open_read_only(src, static=True)
        try:
            summary = _summary(source, src)
            copy_database(source, prepared, overwrite=True)
        except StoreError as err:
            raise InputError(str(src), _detail(err, prepared)) from None
        except sqlite3.Error as err:
            raise InputError(str(src), f"not restored: {err}") from None
        except OSError as err:
            raise InputError(str(database.parent), f"cannot write: {err.strerror or err}") from None
        finally:
            source.close()
        try:
            Store(prepared).close()  # the daemon's own checks, and its migration of an older schema
        except StoreError as err:
            raise InputError(str(src), _detail(err, prepared)) from None
        ready = True
        return prepared, summary
    finally:
        if not ready:
            _remove(prepared)


def _remove(path: Path) -> None:
    for leftover in (path, *(path.with_name(path.name + s) for s in ("-wal", "-shm", "-journal"))):
        with contextlib.suppress(FileNotFoundError):
            leftover.unlink()


# -- shared -----------------------------------------------------------------------------------
def _open_read_only(path: Path, static: bool) -> sqlite3.Connection:
    """A read-only connection to the database ``path``; InputError naming it when it is missing
    or not SQLite.  A running daemon's (not ``static``): its WAL is read, nothing is changed.
    A ``static`` file (a backup) with no WAL beside it is opened immutable, so that SQLite
    makes no WAL or shared-memory file beside it (a raw copy of a WAL-mode database would get
    them)."""
    if not path.exists():
        raise InputError(str(path), "no state database here (the daemon's --state-dir, or [state] dir?)")
    try:
        check_state_file(path)
    except StoreError as err:
        raise InputError(str(path), _detail(err, path)) from None
    alone = static and not path.with_name(path.name + "-wal").exists()
    try:
        return sqlite3.connect(
            path.resolve().as_uri() + ("?immutable=1" if alone else "?mode=ro"), uri=True, timeout=10.0
        )
    except sqlite3.Error as err:
        raise InputError(str(path), f"cannot open: {err}") from None


def _summary(conn: sqlite3.Connection, path: Path) -> dict[str, Any]:
    """What the database holds (moves, learned steps, a camera calibration, its schema version);
    InputError naming ``path`` when it is no feeder state database."""
    try:
        tables = {row[0] for row in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        version = None
        if "meta" in tables:
            rows = conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchall()
            version = str(rows[0][0]) if rows else None
        if version is None or not version.isdigit() or not {"moves", "calibration"} <= tables:
            raise InputError(str(path), "not a feeder state database (no schema version, or no moves)")
        camera = "camera_calibration" in tables and bool(
            conn.execute("SELECT count(*) FROM camera_calibration").fetchone()[0]
        )
        return {
            "schema_version": int(version),
            "moves": int(conn.execute("SELECT count(*) FROM moves").fetchone()[0]),
            "calibrations": int(conn.execute("SELECT count(*) FROM calibration").fetchone()[0]),
            "camera_calibration": camera,
        }
    except sqlite3.Error as err:
        raise InputError(str(path), f"cannot read: {err}") from None


def _file_summary(path: Path) -> dict[str, Any]:
    info = path.stat()
    return {"size_bytes": info.st_size, "mode": f"{stat.S_IMODE(info.st_mode):04o}"}


def _detail(err: StoreError, path: Path) -> str:
    """A store refusal's text without the file name it starts with (the error names the file
    the user gave) and without its advice to ``feeder daemon``."""
    text = str(err)
    prefix = f"{path}: "
    return _DAEMON_HINT.sub("", text[len(prefix) :] if text.startswith(prefix) else text)
