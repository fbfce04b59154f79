"""``feeder demo`` in the plane: the daemon brings a part to poses (x, y, ψ) seen by its camera.

Starts the daemon on the embedded planar world (firmware_sim with three
amplifier axes x, y, θ on a pty or slcan, its plant and its 2048 px camera; the
daemon locates the part in the camera's frames), brings a 300×300×50 µm part
through targets that change position and orientation, prints each target's
error measured from the camera *and* from the simulator's truth, draws the
part's path with its outline at each target (PNG), shuts everything down.
Exit 0 when every move ended within tolerance by both measures.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

from feeder.cli.daemon import launch
from feeder.daemon.client import Client
from feeder.daemon.config import DaemonConfig, embedded_plane
from feeder.errors import FeederError, InputError
from feeder.files import save_figure
from feeder.parts import Part
from feeder.pose import Pose, pose_error

TARGETS: tuple[Pose, ...] = (
    (1.2e-3, 0.7e-3, 0.2),
    (1.2e-3, 0.7e-3, 0.75),  # a turn of 31.5°
    (-0.6e-3, 1.1e-3, 0.75),
    (-0.4e-3, -0.9e-3, 0.3),  # −25.8°
    (0.5e-3, -0.3e-3, 0.0),
)
MOVE_TIMEOUT_S = 120.0


def config_for(part: Part, transport: str, base: Path) -> DaemonConfig:
    """The embedded planar world (:func:`~feeder.daemon.config.embedded_plane`) for ``part``,
    with a fresh state directory under ``base``."""
    config = DaemonConfig(part=part, state_dir=base / "state", socket_path=base / "run" / "s.sock")
    return embedded_plane(config.with_transport(transport))


def true_poses(status: dict[str, Any]) -> list[Pose]:
    """The simulator's true poses (its camera's /truth.json, on 127.0.0.1)."""
    url = (status.get("simulator_endpoints") or {}).get("camera_http")
    if not isinstance(url, str) or not url.startswith("http://127.0.0.1:"):
        raise FeederError(f"the simulator reports no local camera ({url!r})")
    with urllib.request.urlopen(f"{url}/truth.json", timeout=5.0) as reply:
        truth = json.load(reply)
    return [(p["x_m"], p["y_m"], p["psi_rad"]) for p in truth["parts"]]


def run(part: Part, transport: str, plot: Path, quiet: bool) -> tuple[int, dict[str, Any]]:
    """The demo; (exit code, summary)."""
    started = time.monotonic()
    base = Path(tempfile.mkdtemp(prefix="fdemo"))
    config = config_for(part, transport, base)
    if not quiet:
        print(f"starting the daemon on a simulated 3-axis amplifier ({transport}) ...", file=sys.stderr)
    running = launch(config)
    moves: list[dict[str, Any]] = []
    try:
        with Client(config.socket_path, timeout_s=MOVE_TIMEOUT_S) as client:
            status = wait_for_pose(client)
            tol_m, tol_rad = float(status["tolerance_m"]), float(status["tolerance_rad"])
            for i, target in enumerate(TARGETS, start=1):
                result = move_to(client, target, quiet)
                truth = true_poses(client.request("status"))[0]
                true_m, true_rad = pose_error(
                    truth, target, math.pi / 2 if part.length_m == part.width_m else math.pi
                )
                move = {
                    "target": list(target),
                    "pose": result["pose"],
                    "true_pose": list(truth),
                    "error_m": result["error_m"],
                    "error_rad": result["error_rad"],
                    "true_error_m": true_m,
                    "true_error_rad": true_rad,
                    "steps": result["steps"],
                    "bursts": result["bursts"],
                    "bursts_per_axis": result.get("bursts_per_axis", {}),
                    "duration_s": result["duration_s"],
                    "status": result["status"],
                    "trace": [row[1:] for row in result.get("pose_trace", [])],
                }
                moves.append(move)
                if not quiet:
                    print(
                        f"move {i}/{len(TARGETS)}: target ({target[0] * 1e6:7.1f}, "
                        f"{target[1] * 1e6:7.1f}) µm "
                        f"{math.degrees(target[2]):6.2f}°  camera error {move['error_m'] * 1e6:.3f} µm "
                        f"{math.degrees(move['error_rad']):.3f}°  true error {true_m * 1e6:.3f} µm "
                        f"{math.degrees(true_rad):.3f}°  {move['steps']} steps  {move['duration_s']:.1f} s  "
                        f"{move['status']}",
                        flush=True,
                    )
            final = client.request("status")
    finally:
        running.stop()
        shutil.rmtree(base, ignore_errors=True)
    _plot(plot, moves, part)
    worst = {k: max(m[k] for m in moves) for k in ("error_m", "error_rad", "true_error_m", "true_error_rad")}
    ok = all(m["status"] == "done" for m in moves) and (
        max(worst["error_m"], worst["true_error_m"]) <= tol_m
        and max(worst["error_rad"], worst["true_error_rad"]) <= tol_rad
    )
    summary = {
        "moves": [{k: v for k, v in m.items() if k != "trace"} for m in moves],
        "max_error_m": worst["error_m"],
        "max_error_rad": worst["error_rad"],
        "max_true_error_m": worst["true_error_m"],
        "max_true_error_rad": worst["true_error_rad"],
        "tolerance_m": tol_m,
        "tolerance_rad": tol_rad,
        "all_within_tolerance": ok,
        "duration_s": time.monotonic() - started,
        "transport": transport,
        "plot": str(plot),
        "loop_timing": final["timing"],
    }
    return (0 if ok else 1), summary


def move_to(client: Client, target: Pose, quiet: bool = True) -> dict[str, Any]:
    """Move part 1 to ``target``; the result (with its ``pose_trace``).  A move that ends in a
    fault is tried once more when the daemon has recovered: the simulated planar plant runs in
    the firmware's tick, and a rare slow θ slip can stall it past the burst's grace (a real
    amplifier never waits for physics)."""
    result = _attempt(client, target)
    if result["status"] == "fault":
        if not quiet:
            print(f"move to {target}: {result['reason']}; retrying once", file=sys.stderr)
        wait_until_idle(client, MOVE_TIMEOUT_S)
        result = _attempt(client, target)
    return result


def wait_until_idle(client: Client, timeout_s: float) -> None:
    """Wait (at most ``timeout_s``) until the daemon has recovered from a fault and is idle."""
    end = time.monotonic() + timeout_s
    while client.request("status")["state"] != "idle" and time.monotonic() < end:
        time.sleep(0.1)


def _attempt(client: Client, target: Pose) -> dict[str, Any]:
    reply = client.request(
        "move", timeout_s=MOVE_TIMEOUT_S, x_m=target[0], y_m=target[1], angle_rad=target[2], trace=True
    )
    if "result" not in reply:
        raise InputError("demo", f"move to {target} refused: {reply.get('error')}")
    result: dict[str, Any] = reply["result"]
    return result


def wait_for_pose(client: Client, timeout_s: float = 20.0) -> dict[str, Any]:
    """The daemon's status once its camera has located the part."""
    end = time.monotonic() + timeout_s
    while True:
        status = client.request("status")
        if status["parts"] and status["parts"][0]["pose"] is not None:
            return status
        if time.monotonic() > end:
            raise FeederError(f"the camera did not locate the part within {timeout_s:g} s: {status['fault']}")
        time.sleep(0.1)


def _plot(path: Path, moves: list[dict[str, Any]], part: Part) -> None:
    """The part's path in the plate frame, its outline at each target and where it ended."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon

    fig, ax = plt.subplots(figsize=(7, 7))

    def outline(pose: list[float], **style: Any) -> None:
        x, y, psi = pose
        c, s = math.cos(psi), math.sin(psi)
        half = (part.length_m / 2, part.width_m / 2)
        corners = [(sx * half[0], sy * half[1]) for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
        points = [((x + c * u - s * v) * 1e3, (y + s * u + c * v) * 1e3) for u, v in corners]
        ax.add_patch(Polygon(points, closed=True, fill=False, **style))

    numbers: dict[tuple[float, float], list[str]] = {}
    for i, move in enumerate(moves):
        trace = move["trace"]
        if trace:
            ax.plot([p[0] * 1e3 for p in trace], [p[1] * 1e3 for p in trace], color="C0", lw=1,
                    label="path (camera)" if i == 0 else "_")  # fmt: skip
        outline(move["target"], edgecolor="C3", ls="--", lw=1.2)
        outline(move["true_pose"], edgecolor="C2", lw=1.0)
        numbers.setdefault((move["target"][0], move["target"][1]), []).append(str(i + 1))
    for (x, y), names in numbers.items():  # moves to one place (e.g. only turning there) share a label
        ax.annotate(", ".join(names), (x * 1e3, y * 1e3), color="C3", fontsize=9)
    ax.plot([], [], color="C3", ls="--", label="target outline")
    ax.plot([], [], color="C2", label="reached (simulator's truth)")
    ax.plot(0, 0, "k+", ms=10, label="rotation centre O")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title("pose control: the part's path and its outline at each target")
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
