"""What a daemon that is refused, or stopped, leaves of another one (found by an audit of the
state and restarts): nothing of its hardware, socket or database."""

from __future__ import annotations

import dataclasses
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_daemon_service import FakeLinks, make_setup, start, wait_for

from feeder.daemon.service import Daemon, lock_state
from feeder.daemon.store import Store, StoreError
from feeder.errors import InputError

pytestmark = pytest.mark.timeout(60)
ROOT = Path(__file__).resolve().parents[1]


def test_a_second_daemon_on_the_same_socket_is_refused_before_it_opens_its_amplifier(
    short_dir: Path,
) -> None:
    """It opened and grounded its amplifier (the same axis over a TCP console: the first
    daemon's move ended "Axis in wrong mode") and only then found the socket taken."""
    first, _ = start(short_dir / "a")
    try:
        wait_for(lambda: first.loop.position_m is not None)
        links = FakeLinks(first.links.world)  # type: ignore[attr-defined]
        setup = dataclasses.replace(make_setup(short_dir / "b"), socket_path=first.setup.socket_path)
        with pytest.raises(InputError, match="another daemon is already listening there"):
            Daemon(links, setup)
        assert links.amplifiers == [] and links.sensors == []  # never opened: nothing grounded
        assert first.setup.socket_path.exists()
        assert lock_state(setup.database_path).close() is None  # its state lock released
    finally:
        first.shutdown()


def test_a_daemon_stopping_leaves_a_later_daemons_socket_in_place(short_dir: Path) -> None:
    """Its shutdown unlinked whatever was at its socket path: a daemon started there after the
    path was cleared lost its socket, and `feeder stop` could no longer reach it."""
    first, _ = start(short_dir / "a")
    path = first.setup.socket_path
    path.unlink()  # someone clears the path; a second daemon starts on it
    setup = dataclasses.replace(make_setup(short_dir / "b"), socket_path=path)
    second = Daemon(FakeLinks(first.links.world), setup)  # type: ignore[attr-defined]
    second.start()
    try:
        first.shutdown()
        assert path.exists()  # the second's
    finally:
        second.shutdown()
    assert not path.exists()


def test_reset_state_while_a_daemon_uses_the_state_is_refused_and_moves_nothing(short_dir: Path) -> None:
    """It moved the running daemon's live database aside (which then wrote into the .bak)
    before finding the state directory locked."""
    state = short_dir / "state"
    lock = lock_state(state / "feeder.sqlite")  # as a running daemon holds it
    (state / "feeder.sqlite").write_bytes(b"live")
    try:
        done = subprocess.run(
            [sys.executable, "-m", "feeder", "daemon", "--line", "--state-dir", str(state),
             "--socket", str(short_dir / "s.sock"), "--reset-state"],
            cwd=ROOT, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
    finally:
        lock.close()
    assert done.returncode == 2, done.stderr
    assert "another daemon is using this state directory" in done.stderr
    assert (state / "feeder.sqlite").read_bytes() == b"live" and not list(state.glob("*.bak"))


def test_a_state_dir_that_cannot_hold_the_log_is_one_line_and_exit_2(short_dir: Path) -> None:
    """A file given as --state-dir was a FileExistsError traceback (exit 1)."""
    not_a_dir = short_dir / "state"
    not_a_dir.write_text("a file")
    done = subprocess.run(
        [sys.executable, "-m", "feeder", "daemon", "--line", "--state-dir", str(not_a_dir),
         "--socket", str(short_dir / "s.sock")],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and done.stderr.count("\n") == 1
    assert str(not_a_dir) in done.stderr and "cannot hold the log" in done.stderr


def test_a_taken_http_port_is_refused_before_anything_starts_or_is_written(short_dir: Path) -> None:
    """The CLI audit: `feeder daemon --http 127.0.0.1:PORT` on a taken port exited 2 only after
    ~27 s (the simulator started, the planner planned), leaving a fresh state database and token."""
    state = short_dir / "state"
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        begun = time.monotonic()
        done = subprocess.run(
            [sys.executable, "-m", "feeder", "daemon", "--line", "--http", f"127.0.0.1:{port}",
             "--state-dir", str(state), "--socket", str(short_dir / "s.sock")],
            cwd=ROOT, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and f"--http: cannot listen on 127.0.0.1:{port}" in done.stderr
    assert not state.exists() and time.monotonic() - begun < 10.0


@pytest.mark.parametrize("socket_at", ["file", "file/s.sock", "long"])
def test_a_socket_path_that_cannot_be_bound_is_refused_before_anything_is_written(
    short_dir: Path, socket_at: str
) -> None:
    """The CLI audit: `--socket` naming a file, or a path over the 107 bytes a Unix socket
    allows, was refused only after the state directory and its daemon.log had been made."""
    state = short_dir / "state"
    (short_dir / "file").write_text("a file")
    path = str(short_dir / ("x" * 110) / "s.sock") if socket_at == "long" else str(short_dir / socket_at)
    done = subprocess.run(
        [sys.executable, "-m", "feeder", "daemon", "--line", "--state-dir", str(state), "--socket", path],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and done.stderr.count("\n") == 1 and path in done.stderr
    assert not state.exists() and (short_dir / "file").read_text() == "a file"


@pytest.mark.parametrize("below", ["", "sub"])
def test_a_state_lock_in_a_file_is_an_input_error_naming_it(short_dir: Path, below: str) -> None:
    """`vision calibrate-moves --state-dir FILE` (the CLI audit) was a FileExistsError traceback,
    `FILE/sub` a NotADirectoryError one: the state lock made the directory unguarded."""
    not_a_dir = short_dir / "state"
    not_a_dir.write_text("a file")
    with pytest.raises(InputError, match="cannot hold the state") as refused:
        lock_state(not_a_dir / below / "feeder.sqlite")
    assert refused.value.field == str(not_a_dir / below).rstrip("/")
    assert not_a_dir.read_text() == "a file"


def _state_file(path: Path, script: str) -> Path:
    conn = sqlite3.connect(path)
    conn.executescript(script)
    conn.close()
    return path


@pytest.mark.parametrize(
    ("script", "words"),
    [
        (  # int('four'): a ValueError traceback
            "CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);"
            "INSERT INTO meta VALUES ('schema_version', 'four');",
            "schema version 'four' is not a number",
        ),
        (  # later, mid-start: sqlite3.OperationalError "no such column: reason" (exit 1)
            "CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);"
            "INSERT INTO meta VALUES ('schema_version', '4');"
            "CREATE TABLE moves (id INTEGER PRIMARY KEY, status TEXT);",
            "table moves lacks",
        ),
    ],
)
def test_a_state_file_of_a_wrong_schema_is_refused_by_name(short_dir: Path, script: str, words: str) -> None:
    path = _state_file(short_dir / "feeder.sqlite", script)
    with pytest.raises(StoreError) as err:
        Store(path)
    assert str(path) in str(err.value) and words in str(err.value) and "\n" not in str(err.value)


def test_the_state_files_are_owner_only_in_a_folder_open_to_others(short_dir: Path) -> None:
    """The WAL holds nearly everything (the main file 4 KiB, the WAL 240 KiB) and was 0644, as
    were the SHM and lock files, in a state directory readable by others."""
    folder = short_dir / "state"
    folder.mkdir(mode=0o755)
    folder.chmod(0o755)
    lock = lock_state(folder / "feeder.sqlite")
    store = Store(folder / "feeder.sqlite")
    try:
        store.save_position(1e-4)
        names = ("feeder.sqlite", "feeder.sqlite-wal", "feeder.sqlite-shm", "feeder.sqlite.lock")
        assert {name: oct((folder / name).stat().st_mode & 0o777) for name in names} == dict.fromkeys(
            names, "0o600"
        )
    finally:
        store.close()
        lock.close()
