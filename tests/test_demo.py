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


@pytest.mark.timeout(240)
def test_the_demo_in_the_plane_brings_the_part_to_poses_by_camera_and_by_truth(tmp_path: Path) -> None:
    pytest.importorskip("cv2", reason="the camera needs OpenCV (the vision extra)")
    plot = tmp_path / "plane.png"
    done = feeder("demo", "--json", "--plot", str(plot), cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout)
    moves = out["moves"]
    assert len(moves) >= 4 and all(m["status"] == "done" for m in moves)
    for key in ("error_m", "error_rad", "true_error_m", "true_error_rad"):
        assert out[f"max_{key}"] == max(m[key] for m in moves)
    assert max(out["max_error_m"], out["max_true_error_m"]) <= out["tolerance_m"] == 1e-6
    assert max(out["max_error_rad"], out["max_true_error_rad"]) <= out["tolerance_rad"]
    assert max(abs(b["target"][2] - a["target"][2]) for a, b in itertools.pairwise(moves)) >= 0.52  # 30°
    assert all(len(m["target"]) == len(m["pose"]) == 3 for m in moves)
    assert out["duration_s"] > 0 and plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_demo_refuses_a_plot_path_that_is_not_png(tmp_path: Path) -> None:
    done = feeder("demo", "--plot", str(tmp_path / "demo.svg"), cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "--plot" in done.stderr
    assert not (tmp_path / "demo.svg").exists()


def test_demo_refuses_a_plot_in_a_folder_that_does_not_exist(tmp_path: Path) -> None:
    """The CLI audit: `--plot /nonexist/x.png` made /nonexist (exit 0); `vision locate --plot`
    refused the same.  Only the default's folder (out/) is made."""
    done = feeder("demo", "--plot", str(tmp_path / "typo" / "demo.png"), cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "--plot" in done.stderr and "no such directory" in done.stderr
    assert not (tmp_path / "typo").exists()


def test_demo_refuses_a_default_plot_folder_it_cannot_make(tmp_path: Path) -> None:
    """`out` a file in the working directory: one line naming --plot, not a FileExistsError."""
    (tmp_path / "out").write_text("a file")
    done = feeder("demo", "--line", cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr == "feeder demo: error: --plot: cannot make out/: File exists\n"
