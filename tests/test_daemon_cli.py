"""``feeder move|status|stop|calibrate|history`` against an in-process daemon on the fake world."""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_daemon_service import start

from feeder.cli import main
from feeder.daemon.service import Daemon

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def daemon() -> Iterator[tuple[Daemon, str]]:
    base = Path(tempfile.mkdtemp(prefix="fd"))
    running, _ = start(base)
    yield running, str(base / "run" / "f.sock")
    running.shutdown()
    shutil.rmtree(base, ignore_errors=True)


def test_move_absolute_and_relative_then_history(daemon, capsys) -> None:
    _, sock = daemon
    assert main(["move", "150e-6", "--socket", sock, "--json"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["status"] == "done" and abs(first["error_m"]) <= 1e-6
    assert main(["move", "--by", "-50e-6", "--socket", sock, "--json"]) == 0
    second = json.loads(capsys.readouterr().out)
    # relative to the latest sensor frame (noise 0.05 µm), not to the averaged reached position
    assert second["target_m"] == pytest.approx(first["reached_m"] - 50e-6, abs=0.5e-6)
    assert main(["history", "--socket", sock, "--json"]) == 0
    moves = json.loads(capsys.readouterr().out)["moves"]
    assert [m["status"] for m in moves] == ["done", "done"]
    assert main(["status", "--socket", sock]) == 0
    text = capsys.readouterr().out
    assert "state: idle" in text and "step coarse/forward" in text


def test_refusals_are_one_line_exit_2(daemon, capsys) -> None:
    _, sock = daemon
    assert main(["move", "1.0", "--socket", sock]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "travel limits" in err
    assert main(["move", "--socket", sock]) == 2
    assert main(["status", "--socket", "/tmp/fd-no-such-dir/x.sock"]) == 2
    assert "no daemon socket" in capsys.readouterr().err


def test_stop_with_nothing_moving_and_calibrate(daemon, capsys) -> None:
    _, sock = daemon
    assert main(["stop", "--socket", sock, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["stopped"] is False
    assert main(["calibrate", "--socket", sock, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["kind"] == "calibrate" and result["status"] == "done"
    assert result["estimates"]["coarse/forward"]["steps"] >= 20
