"""``feeder demo``: the daemon on a simulated amplifier brings a part to a set of targets.

By default in the plane (:mod:`feeder.cli.demo_plane`: poses x, y, ψ from the
camera, three amplifier axes).  With ``--line``, today's one-axis feeder: the
daemon on the embedded default (firmware_sim on a pty, real-time clock, its
position stream on a local port) with a fresh state directory moves a
300×300×50 µm part to each target in turn (both ways), prints one line per
move, writes a PNG of position vs time with the targets, shuts everything
down.  Exit 0 when every move ended within tolerance.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from feeder.cli import demo_plane
from feeder.cli.arguments import output_path
from feeder.cli.daemon import launch
from feeder.cli.demo_plane import wait_until_idle
from feeder.cli.output import print_json
from feeder.daemon.client import Client
from feeder.daemon.config import TRANSPORTS, DaemonConfig
from feeder.errors import InputError
from feeder.files import save_figure
from feeder.parts import Part

DEFAULT_PLOT = Path("out/demo.png")
"""Where the demo draws its plot unless told (relative to the working directory)."""
DEFAULT_TARGETS_M = (300e-6, 120e-6, 480e-6, -150e-6, -140e-6, 0.0, 250e-6, 247.5e-6)
MOVE_TIMEOUT_S = 20.0
RECOVERY_TIMEOUT_S = 10.0


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("demo", help="closed-loop positioning on a simulated amplifier")
    parser.add_argument("--part", default="300x300x50", help="LxWxT in µm")
    parser.add_argument("--transport", choices=TRANSPORTS, default="serial")
    parser.add_argument(
        "--line",
        action="store_true",
        help="one axis (x) and a position stream instead of poses from a camera",
    )
    parser.add_argument(
        "--plot",
        type=output_path,
        help=f"PNG of the path and the targets (default {DEFAULT_PLOT}, its folder made if missing)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON summary")
    parser.set_defaults(handler=run)


def _progress(done: int, total: int) -> str:
    width = 20
    filled = round(width * done / total)
    return f"[{'#' * filled}{'.' * (width - filled)}] {done}/{total}"


def _attempt(client: Client, target: float) -> tuple[dict[str, Any] | None, list[list[float]], str]:
    """One move request: (result or None when refused, trace, why it did not end done)."""
    reply = client.request("move", timeout_s=MOVE_TIMEOUT_S, target_m=target, trace=True)
    if "result" not in reply:
        return None, [], f"refused: {reply.get('error')}"
    result = reply["result"]
    return result, result.pop("trace"), f"{result['status']}: {result['reason']}"


def _move(client: Client, target: float, quiet: bool) -> tuple[dict[str, Any], list[list[float]]]:
    """Move to ``target``; after a fault (e.g. a late tick on a busy machine made the firmware
    ground itself) wait for the daemon to recover and try once more.  (result, trace)."""
    result, trace, reason = _attempt(client, target)
    if result is not None and result["status"] == "done":
        return result, trace
    if not quiet:
        print(f"move to {target * 1e6:.3f} µm: {reason}; retrying once", file=sys.stderr)
    wait_until_idle(client, RECOVERY_TIMEOUT_S)
    again, more, reason = _attempt(client, target)
    if again is None:
        raise InputError("demo", f"move to {target} m {reason}")
    return again, trace + more


def run(args: argparse.Namespace) -> int:
    part = Part.parse(args.part)
    if args.plot is None:  # only the default's folder is made: a mistyped one is refused
        try:
            DEFAULT_PLOT.parent.mkdir(exist_ok=True)
        except OSError as err:  # a file of that name, no permission
            raise InputError("--plot", f"cannot make {DEFAULT_PLOT.parent}/: {err.strerror}") from None
        args.plot = DEFAULT_PLOT
    if args.plot.suffix.lower() != ".png":
        raise InputError("--plot", f"expected a .png path, got {str(args.plot)!r}")
    if not args.line:
        return run_plane(part, args)
    started = time.monotonic()
    base = Path(tempfile.mkdtemp(prefix="fdemo"))
    config = DaemonConfig(
        part=part, state_dir=base / "state", socket_path=base / "run" / "s.sock"
    ).with_transport(args.transport)
    if not args.json:
        print(
            f"starting the daemon on a simulated amplifier ({args.transport}) ...",
            file=sys.stderr,
            flush=True,
        )
    running = launch(config)
    results: list[dict[str, Any]] = []
    traces: list[list[list[float]]] = []
    try:
        with Client(config.socket_path, timeout_s=MOVE_TIMEOUT_S) as client:
            tolerance = float(client.request("status")["tolerance_m"])
            for i, target in enumerate(DEFAULT_TARGETS_M, start=1):
                result, trace = _move(client, target, quiet=args.json)
                traces.append(trace)
                direction = "forward" if target >= (result["start_m"] or 0.0) else "backward"
                result["learned_step_m"] = result["estimates"][f"coarse/{direction}"]["step_m"]
                results.append(result)
                if not args.json:
                    print(
                        f"move {i}/{len(DEFAULT_TARGETS_M)}: target {target * 1e6:9.3f} µm  "
                        f"reached {result['reached_m'] * 1e6:9.3f} µm  error "
                        f"{result['error_m'] * 1e6:+7.3f} µm  {result['steps']:4d} steps  "
                        f"learned step {result['learned_step_m'] * 1e6:.3f} µm ({direction})  "
                        f"{result['duration_s']:.2f} s  {result['status']}",
                        flush=True,
                    )
                    print(_progress(i, len(DEFAULT_TARGETS_M)), file=sys.stderr, flush=True)
            final = client.request("status")
    finally:
        running.stop()
        shutil.rmtree(base, ignore_errors=True)
    _plot(args.plot, traces, list(DEFAULT_TARGETS_M), tolerance)
    errors = [abs(r["error_m"]) for r in results if r["error_m"] is not None]
    max_error = max(errors) if errors else float("nan")
    duration = time.monotonic() - started
    ok = (
        all(r["status"] == "done" for r in results) and len(errors) == len(results) and max_error <= tolerance
    )
    summary: dict[str, Any] = {
        "moves": [
            {
                k: r[k]
                for k in (
                    "target_m",
                    "reached_m",
                    "error_m",
                    "steps",
                    "bursts",
                    "learned_step_m",
                    "duration_s",
                    "status",
                )
            }
            for r in results
        ],
        "max_error_m": max_error,
        "tolerance_m": tolerance,
        "all_within_tolerance": ok,
        "duration_s": duration,
        "plot": str(args.plot),
        "tau_true_pa": (final.get("simulator_true") or {}).get("tau_pa"),
        "loop_timing": final["timing"],
    }
    if args.json:
        print_json(summary)
    else:
        timing = final["timing"]
        print(
            f"{len(results)} moves, max error {max_error * 1e6:.3f} µm "
            f"(tolerance ±{tolerance * 1e6:.3f} µm), {duration:.1f} s; plot: {args.plot}"
        )
        print(
            f"control loop: {timing['ticks']} ticks at {timing['rate_hz']:g} Hz, "
            f"{timing['overruns']} overruns, jitter p99 {timing['jitter_p99_s'] * 1e3:.2f} ms, "
            f"max {timing['jitter_max_s'] * 1e3:.2f} ms"
        )
    return 0 if ok else 1


def run_plane(part: Part, args: argparse.Namespace) -> int:
    """The demo in the plane; prints its moves (as they end) and a summary."""
    code, summary = demo_plane.run(part, args.transport, args.plot, quiet=args.json)
    if args.json:
        print_json(summary)
    else:
        timing = summary["loop_timing"]
        print(
            f"{len(summary['moves'])} pose moves, max error {summary['max_error_m'] * 1e6:.3f} µm "
            f"{math.degrees(summary['max_error_rad']):.3f}° by the camera, "
            f"{summary['max_true_error_m'] * 1e6:.3f} µm {math.degrees(summary['max_true_error_rad']):.3f}° "
            f"by the simulator's truth (tolerance {summary['tolerance_m'] * 1e6:g} µm, "
            f"{math.degrees(summary['tolerance_rad']):g}°), {summary['duration_s']:.1f} s; plot: {args.plot}"
        )
        print(
            f"control loop: {timing['ticks']} ticks at {timing['rate_hz']:g} Hz, "
            f"{timing['overruns']} overruns, jitter p99 {timing['jitter_p99_s'] * 1e3:.2f} ms; "
            f"the planner's longest decision {timing['decision_max_s'] * 1e3:.1f} ms (off the tick), "
            f"the longest garbage collection {timing['collection_max_s'] * 1e3:.1f} ms (in the tick's slack)"
        )
    return code


def _plot(path: Path, traces: list[list[list[float]]], targets: list[float], tolerance_m: float) -> None:
    """Position vs time, the targets as a staircase, written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t0 = traces[0][0][0] if traces and traces[0] else 0.0
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for i, (trace, target) in enumerate(zip(traces, targets, strict=False)):
        if not trace:
            continue
        times = [(t - t0) for t, _ in trace]
        ax.plot(
            times,
            [x * 1e6 for _, x in trace],
            color="C0",
            lw=1.2,
            label="part position (camera)" if i == 0 else "_",
        )
        ax.hlines(
            target * 1e6,
            times[0],
            times[-1],
            colors="C3",
            linestyles="--",
            lw=1,
            label="target" if i == 0 else "_",
        )
    ax.set_xlabel("time (s)")
    ax.set_ylabel("position (µm)")
    ax.set_title(f"closed-loop moves, tolerance ±{tolerance_m * 1e6:g} µm")
    ax.legend(loc="best")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
