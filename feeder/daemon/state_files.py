"""The state database's files as files: the check that one is an SQLite database, consistent
copies (a backup, or what a store held when its file was removed), and moving one aside.
:class:`~feeder.daemon.store.Store` and ``feeder state`` / ``feeder daemon --reset-state`` use them.
"""

from __future__ import annotations

import contextlib
import errno
import os
import sqlite3
import tempfile
import time
from pathlib import Path

from feeder.errors import FeederError


class StoreError(FeederError, RuntimeError):
    """The state database is unusable (corrupt, newer schema, not a database), or was removed or
    replaced while the store had it open."""


def file_id(path: Path) -> tuple[int, int] | None:
    """The (st_dev, st_ino) of the file at ``path``; None when there is none."""
    try:
        info = os.stat(path)
    except FileNotFoundError:
        return None
    return info.st_dev, info.st_ino


def free_name(path: Path) -> Path:
    """``path``, or ``path`` with ``.1``, ``.2``, ... added when it is taken."""
    candidate, n = path, 0
    while candidate.exists():
        n += 1
        candidate = path.with_name(f"{path.name}.{n}")
    return candidate


def copy_database(
    source: sqlite3.Connection, dest: Path, *, overwrite: bool = False, check: bool = True
) -> None:
    """A consistent copy of ``source``'s database at ``dest``, by SQLite's online backup (its
    writers go on meanwhile; what is only in its WAL is copied too): one file on its own
    (rollback journal, nothing beside it), owner-only (0600), written to a temporary file in
    ``dest``'s folder and renamed, so ``dest`` is either whole or untouched.  An existing
    ``dest`` is replaced only with ``overwrite``, else :class:`FileExistsError`.  With
    ``check`` the copy passes SQLite's full integrity check before it is renamed
    (:class:`StoreError` naming ``dest`` otherwise).  ``OSError`` and ``sqlite3.Error`` pass
    through; the temporary file is removed whatever fails."""
    handle, name = tempfile.mkstemp(dir=dest.parent, prefix=f".{dest.name}.", suffix=".tmp")  # 0600
    os.close(handle)
    tmp = Path(name)
    placed = False
    try:
        copy = sqlite3.connect(tmp, isolation_level=None)
        try:
            source.backup(copy)
            copy.execute("PRAGMA journal_mode=DELETE")  # the source's WAL mode came with its header
            verdict = copy.execute("PRAGMA integrity_check").fetchone()[0] if check else "ok"
        finally:
            copy.close()
        if verdict != "ok":
            raise StoreError(f"{dest}: the copy failed its integrity check: {verdict}")
        fsync_path(tmp)
        if overwrite:
            os.replace(tmp, dest)
        else:
            _place_new(tmp, dest)
        placed = True
        fsync_path(dest.parent)
    finally:
        if not placed:
            for leftover in (tmp, *(tmp.with_name(tmp.name + s) for s in ("-journal", "-wal", "-shm"))):
                with contextlib.suppress(FileNotFoundError):
                    leftover.unlink()


def _place_new(tmp: Path, dest: Path) -> None:
    """Rename ``tmp`` to ``dest`` unless ``dest`` exists (:class:`FileExistsError`): a hard link,
    which never replaces, where the file system has them."""
    try:
        os.link(tmp, dest)
    except FileExistsError:
        raise
    except OSError as err:
        if err.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EMLINK, errno.EXDEV):
            raise
        if dest.exists() or dest.is_symlink():  # no hard links here (FAT, some FUSE): check, then rename
            raise FileExistsError(errno.EEXIST, "file exists", str(dest)) from None
        os.replace(tmp, dest)
        return
    tmp.unlink()


def fsync_path(path: Path) -> None:
    """Flush a file, or a folder's entries (a rename in it), to the disk."""
    handle = os.open(path, os.O_RDONLY)
    try:
        os.fsync(handle)
    finally:
        os.close(handle)


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
    target = free_name(path.with_name(f"{path.name}.{stamp}.bak"))  # never over an earlier one
    for suffix in ("-wal", "-shm"):
        side = path.with_name(path.name + suffix)
        if side.exists():
            side.replace(target.with_name(target.name + suffix))
    path.replace(target)
    return target
