"""``feeder state backup|restore``: a consistent copy of a running daemon's state (WAL included),
and a restore that checks the file and refuses while a daemon runs."""

from __future__ import annotations

import dataclasses
import json
import os
import sqlite3
from pathlib import Path

import pytest
from test_control_loop import TRUE
from test_daemon_doubles import FakeWorld
from test_daemon_service import FakeLinks, make_setup

from feeder.cli import main
from feeder.daemon.client import Client
from feeder.daemon.service import Daemon
from feeder.daemon.store import SCHEMA_VERSION, Store

pytestmark = pytest.mark.timeout(60)


def start(base: Path) -> Daemon:
    """An in-process daemon (fake world) whose state is where ``feeder daemon --state-dir
    BASE/state`` keeps it."""
    setup = dataclasses.replace(make_setup(base), database_path=base / "state" / "feeder.sqlite")
    daemon = Daemon(FakeLinks(FakeWorld(TRUE, scatter=0.03, noise_m=0.05e-6, seed=3)), setup)
    daemon.start()
    return daemon


def _history(path: Path) -> list[tuple[float, str]]:
    store = Store(path)
    try:
        return [(m["target_m"], m["status"]) for m in store.moves()]
    finally:
        store.close()


def _listing(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _one_line_error(capsys: pytest.CaptureFixture[str], start: str) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(start), err
    return err


def _state_with_moves(state: Path, *targets: float) -> Path:
    database = state / "feeder.sqlite"
    store = Store(database)
    for target in targets:
        store.begin_move(target, 0.0)
    store.close()
    return database


def test_a_backup_of_a_running_daemon_holds_all_it_recorded_and_restores(
    short_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """What the daemon wrote since SQLite last checkpointed is in its WAL only (a `cp` of the
    database file misses it): the backup has it, as one file; restored, it is the history again."""
    daemon = start(short_dir)
    state = short_dir / "state"
    dest = short_dir / "backups" / "state.sqlite"
    dest.parent.mkdir()
    try:
        with Client(short_dir / "run" / "f.sock") as client:
            for target in (60e-6, -40e-6, 20e-6):
                assert client.request("move", target_m=target)["ok"]
            history = [(m["target_m"], m["status"]) for m in client.request("history")["moves"]]
        assert (state / "feeder.sqlite-wal").stat().st_size > 0  # the moves are (also) in the WAL
        capsys.readouterr()
        assert main(["state", "backup", "--state-dir", str(state), str(dest), "--json"]) == 0
        out = json.loads(capsys.readouterr().out)
        # restoring is refused while the daemon runs: one line, exit 2, nothing changed
        before = _listing(state)
        assert main(["state", "restore", "--state-dir", str(state), str(dest)]) == 2
        _one_line_error(capsys, f"feeder state: error: {state}: a daemon is using this state directory")
        assert _listing(state).keys() == before.keys()
    finally:
        daemon.shutdown()
    assert out["backup"] == str(dest) and out["moves"] == 3 and out["schema_version"] == SCHEMA_VERSION
    assert out["database"] == str(state / "feeder.sqlite") and out["size_bytes"] == dest.stat().st_size
    assert out["calibrations"] > 0 and out["mode"] == "0600"
    assert oct(dest.stat().st_mode & 0o777) == "0o600"
    assert sorted(p.name for p in dest.parent.iterdir()) == ["state.sqlite"]  # no WAL, no temporary
    conn = sqlite3.connect(dest)
    assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "delete"  # a file on its own
    conn.close()
    assert _history(dest) == history

    # the daemon stopped, moves made since the backup are undone by restoring it
    daemon = start(short_dir)
    try:
        with Client(short_dir / "run" / "f.sock") as client:
            assert client.request("move", target_m=90e-6)["ok"]
    finally:
        daemon.shutdown()
    capsys.readouterr()
    assert main(["state", "restore", "--state-dir", str(state), str(dest), "--json"]) == 0
    restored = json.loads(capsys.readouterr().out)
    assert restored["restored"] == str(state / "feeder.sqlite") and restored["from"] == str(dest)
    assert restored["moves"] == 3
    previous = Path(restored["previous"])
    assert previous.parent == state and previous.name.startswith("feeder.sqlite.")
    assert previous.suffix == ".bak"
    assert [t for t, _ in _history(previous)] == [60e-6, -40e-6, 20e-6, 90e-6]  # kept, not lost
    assert _history(state / "feeder.sqlite") == history
    assert oct((state / "feeder.sqlite").stat().st_mode & 0o777) == "0o600"
    assert not list(state.glob(".*"))  # no temporary left


def test_a_backup_never_replaces_a_file_without_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _state_with_moves(tmp_path / "state", 1e-6, 2e-6)
    dest = tmp_path / "old.sqlite"
    dest.write_bytes(b"an older backup")
    args = ["state", "backup", "--state-dir", str(tmp_path / "state"), str(dest)]
    assert main(args) == 2
    _one_line_error(capsys, f"feeder state: error: {dest}: exists; --force replaces it")
    assert dest.read_bytes() == b"an older backup"
    assert main([*args, "--force"]) == 0
    assert "(moves 2, learned steps 0," in capsys.readouterr().out
    assert [t for t, _ in _history(dest)] == [1e-6, 2e-6]


@pytest.mark.parametrize(
    ("content", "why"),
    [
        (None, "no state database here"),
        (b"", "empty file"),
        (b"not a database at all" * 10, "not an SQLite database"),
        ("foreign", "not a feeder state database"),
        ("corrupt", "malformed"),
    ],
)
def test_a_backup_of_no_state_database_is_refused_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes | str | None, why: str
) -> None:
    state = tmp_path / "state"
    state.mkdir()
    database = state / "feeder.sqlite"
    if content == "foreign":
        conn = sqlite3.connect(database)
        conn.execute("CREATE TABLE parts (name TEXT)")
        conn.commit()
        conn.close()
    elif content == "corrupt":
        _corrupt(database)
    elif isinstance(content, bytes):
        database.write_bytes(content)
    before = _listing(state)
    dest = tmp_path / "out" / "b.sqlite"
    dest.parent.mkdir()
    assert main(["state", "backup", "--state-dir", str(state), str(dest)]) == 2
    err = _one_line_error(capsys, f"feeder state: error: {database}: ")
    assert why in err and "--reset-state" not in err
    assert list(dest.parent.iterdir()) == []  # nothing written, not even a temporary
    after = _listing(state)  # unchanged (a reader's SQLite may add its -shm and -wal)
    assert {k: v for k, v in after.items() if k not in before}.keys() <= {
        "feeder.sqlite-shm",
        "feeder.sqlite-wal",
    }
    assert {k: after[k] for k in before} == before


@pytest.mark.parametrize("where", ["folder", "missing folder", "the database", "its WAL"])
def test_a_backup_to_a_place_it_cannot_go_is_refused_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], where: str
) -> None:
    database = _state_with_moves(tmp_path / "state", 1e-6)
    dest = {
        "folder": tmp_path,
        "missing folder": tmp_path / "nowhere" / "b.sqlite",
        "the database": database,
        "its WAL": database.with_name("feeder.sqlite-wal"),
    }[where]
    before = _listing(database.parent)
    assert main(["state", "backup", "--state-dir", str(database.parent), str(dest), "--force"]) == 2
    _one_line_error(capsys, f"feeder state: error: {dest}: ")
    assert _listing(database.parent) == before


def _newer(path: Path) -> None:
    store = Store(path)
    store.close()
    conn = sqlite3.connect(path)
    conn.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'", (str(SCHEMA_VERSION + 1),))
    conn.commit()
    conn.close()


def _corrupt(path: Path) -> None:
    store = Store(path)
    for i in range(200):
        store.begin_move(i * 1e-6, 0.0)
    store.close()
    with open(path, "r+b") as handle:  # a page of the moves' table overwritten
        handle.seek(3 * 4096)
        handle.write(os.urandom(4096))


@pytest.mark.parametrize(
    ("make", "why"),
    [
        (lambda p: p.write_bytes(b""), "empty file"),
        (lambda p: p.write_bytes(b"SQLite format 3\x00 but cut short"), "not an SQLite database"),
        (lambda p: p.write_text("[state]\ndir = 'x'\n"), "not an SQLite database"),
        (_newer, "newer than this feeder"),
        (_corrupt, ""),
    ],
    ids=["empty", "truncated", "text", "newer schema", "corrupt"],
)
def test_a_restore_of_a_bad_file_is_refused_naming_it_and_changes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], make, why: str
) -> None:
    database = _state_with_moves(tmp_path / "state", 5e-6)
    src = tmp_path / "bad.sqlite"
    make(src)
    before = _listing(database.parent)
    assert main(["state", "restore", "--state-dir", str(database.parent), str(src)]) == 2
    err = _one_line_error(capsys, f"feeder state: error: {src}: ")
    assert why in err
    after = _listing(database.parent)
    assert after.keys() - {"feeder.sqlite.lock"} == before.keys()  # the lock taken: left beside it
    assert after["feeder.sqlite"] == before["feeder.sqlite"]
    assert [t for t, _ in _history(database)] == [5e-6]


def test_a_restore_from_a_missing_file_or_the_database_itself_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    database = _state_with_moves(tmp_path / "state", 5e-6)
    for src, why in ((tmp_path / "none.sqlite", "no such file"), (database, "is the state database itself")):
        assert main(["state", "restore", "--state-dir", str(database.parent), str(src)]) == 2
        assert why in _one_line_error(capsys, f"feeder state: error: {src}: ")
    assert [t for t, _ in _history(database)] == [5e-6]


def test_a_restore_into_an_empty_state_directory_and_of_an_older_schema(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The daemon's own check and migration run on the copy, never on the file given."""
    src = tmp_path / "v3.sqlite"
    _state_with_moves(tmp_path, 3e-6)
    (tmp_path / "feeder.sqlite").rename(src)
    conn = sqlite3.connect(src)
    conn.execute("UPDATE meta SET value = '3' WHERE key = 'schema_version'")
    conn.commit()
    conn.close()
    given = src.read_bytes()
    state = tmp_path / "fresh" / "state"
    assert main(["state", "restore", "--state-dir", str(state), str(src)]) == 0
    assert "there was none" in capsys.readouterr().out
    assert src.read_bytes() == given and not src.with_name("v3.sqlite-wal").exists()
    store = Store(state / "feeder.sqlite")
    try:
        assert store._meta("schema_version") == str(SCHEMA_VERSION)
        assert [m["target_m"] for m in store.moves()] == [3e-6]
    finally:
        store.close()
