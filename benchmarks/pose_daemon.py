"""Pose control end to end: the daemon on the embedded planar world brings a part to random poses.

``feeder daemon --plane`` in-process (firmware_sim's three axes on a pty, its
planar plant and 2048 px camera, the daemon locating the part): 20 random
reachable targets (quick: 4), centres within ±1.5 mm, angles within ±40°.
Reported: the median wall time to reach a target (the simulator runs in real
time: simulated time = wall time), the median steps, and ``ratio`` = the
fewest steps the plant model allows over the steps used (higher is better,
1 at best): per target |Δx|/coarse x step + |Δy|/coarse y step + |Δψ|/largest
coarse turn per step, with the steps the daemon had learned (its status).
"""

from __future__ import annotations

import random
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from feeder.cli.demo_plane import config_for, wait_for_pose
from feeder.daemon.client import Client
from feeder.daemon.runner import start_daemon
from feeder.parts import Part
from feeder.pose import pose_error

SQUARE_RAD = 1.5707963267948966


def run(quick: bool) -> dict[str, float | int]:
    rng = random.Random(20)
    targets = [
        (rng.uniform(-1.5e-3, 1.5e-3), rng.uniform(-1.5e-3, 1.5e-3), rng.uniform(-0.7, 0.7))
        for _ in range(4 if quick else 20)
    ]
    base = Path(tempfile.mkdtemp(prefix="fbench"))
    config = config_for(Part.parse("300x300x50"), "serial", base)
    running = start_daemon(config)
    walls, steps, bounds, done = [], [], [], 0
    try:
        with Client(config.socket_path, timeout_s=180.0) as client:
            wait_for_pose(client)
            for target in targets:
                before = client.status()
                start = time.monotonic()
                reply = client.request(
                    "move", timeout_s=180.0, x_m=target[0], y_m=target[1], angle_rad=target[2]
                )
                walls.append(time.monotonic() - start)
                result = reply.get("result") or {}
                done += result.get("status") == "done"
                steps.append(int(result.get("steps", 0)))
                axes = client.status().raw["axes"]
                pose = before.parts[0].pose or target
                distance_x, distance_y = abs(target[0] - pose[0]), abs(target[1] - pose[1])
                turn = pose_error(pose, target, SQUARE_RAD)[1]
                turn_step = abs(axes["theta"].get("step_rad") or 0.0) or float("inf")
                bounds.append(
                    distance_x / axes["x"]["step_m"] + distance_y / axes["y"]["step_m"] + turn / turn_step
                )
    finally:
        running.stop()
        shutil.rmtree(base, ignore_errors=True)
    return {
        "ratio": sum(bounds) / max(sum(steps), 1),
        "targets": len(targets),
        "reached": done,
        "median_wall_s": statistics.median(walls),
        "max_wall_s": max(walls),
        "median_steps": statistics.median(steps),
        "median_lower_bound_steps": statistics.median(bounds),
    }
