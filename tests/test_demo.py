"""`feeder demo`: the daemon on the simulated amplifier, end to end, as `make demo` runs it."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def feeder(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "feeder", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )


@pytest.mark.timeout(150)
def test_demo_json_summary_and_plot(tmp_path: Path) -> None:
    plot = tmp_path / "demo.png"
    done = feeder("demo", "--line", "--json", "--plot", str(plot), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    moves = summary["moves"]
    assert len(moves) >= 6
    assert all(m["status"] == "done" for m in moves)
    assert summary["max_error_m"] == max(abs(m["error_m"]) for m in moves)
    assert summary["max_error_m"] <= summary["tolerance_m"] == 1e-6
    targets = [m["target_m"] for m in moves]
    steps = [b - a for a, b in itertools.pairwise(targets)]
    assert any(s > 0 for s in steps) and any(s < 0 for s in steps)  # both ways
    assert summary["duration_s"] > 0
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert done.stderr == ""  # no progress in --json


def test_demo_refuses_a_plot_path_that_is_not_png(tmp_path: Path) -> None:
    done = feeder("demo", "--plot", str(tmp_path / "demo.svg"), cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "--plot" in done.stderr
    assert not (tmp_path / "demo.svg").exists()
