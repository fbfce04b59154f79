"""Soak in the plane (``--runslow``): the daemon brings a part to many random poses on the embedded
planar world (firmware_sim's plant and camera), over both transports, with no retry.

Every move must end ``done`` within tolerance by the camera and by the simulator's truth, the
history must hold each of them, and the state database must pass SQLite's integrity check.  A move
that ends in a fault (a slow simulated tick past the burst's grace) fails the soak: ``feeder demo``
retries such a move once, and this counts whether it still has to.
"""

from __future__ import annotations

import math
import shutil
import sqlite3
import tempfile
from pathlib import Path

import pytest
from test_plane_hil import CAMERA_M, CAMERA_RAD, PART, SQUARE, random_targets

from feeder.cli.demo_plane import config_for, true_poses, wait_for_pose, wait_until_idle
from feeder.daemon.client import Client
from feeder.daemon.runner import start_daemon
from feeder.pose import pose_error

pytest.importorskip("cv2", reason="the camera needs OpenCV (the vision extra)")
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]

MOVES = 25


@pytest.mark.parametrize("transport", ["can", "serial"])
def test_many_random_poses_all_end_done_without_a_retry(transport: str) -> None:
    base = Path(tempfile.mkdtemp(prefix="fsoak"))
    config = config_for(PART, transport, base)
    targets = random_targets(MOVES, seed=29)
    running = start_daemon(config)
    misses: list[str] = []
    try:
        with Client(config.socket_path, timeout_s=180.0) as client:
            status = wait_for_pose(client)
            tol_m, tol_rad = status["tolerance_m"], status["tolerance_rad"]
            for i, target in enumerate(targets):
                x_m, y_m, angle_rad = target
                reply = client.request("move", timeout_s=120.0, x_m=x_m, y_m=y_m, angle_rad=angle_rad)
                result = reply["result"]
                truth = true_poses(client.request("status"))[0]
                true_m, true_rad = pose_error(truth, target, SQUARE)
                if result["status"] != "done" or true_m > tol_m + CAMERA_M or true_rad > tol_rad + CAMERA_RAD:
                    misses.append(
                        f"move {i} to {target}: {result['status']} ({result.get('reason')}), truth "
                        f"{true_m * 1e6:.3f} µm {math.degrees(true_rad):.3f}° off"
                    )
                if result["status"] == "fault":
                    wait_until_idle(client, 60.0)
            history = client.request("history", limit=MOVES)["moves"]
    finally:
        running.stop()
    try:
        assert not misses, "\n".join(misses)
        assert len(history) == MOVES and all(move["status"] == "done" for move in history)
        database = next(p for p in (base / "state").iterdir() if p.suffix in (".sqlite", ".db"))
        with sqlite3.connect(database) as db:
            assert db.execute("PRAGMA integrity_check").fetchone() == ("ok",)
    finally:
        shutil.rmtree(base, ignore_errors=True)
