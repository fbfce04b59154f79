"""``feeder move|status|stop|calibrate|history|shutdown``: clients of the running daemon's socket.

Light to import (no numpy): ``feeder status`` starts in well under 0.5 s.  Errors
become exit codes in :func:`feeder.cli.main`: 1 refused or failed, 2 bad input,
3 unreachable or no answer within ``--timeout``.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from feeder.cli.arguments import angle_rad, int_in, length_m, positive_float
from feeder.cli.output import print_json
from feeder.daemon.client import DEFAULT_TIMEOUT_S, Client
from feeder.daemon.client_connection import default_socket_path
from feeder.daemon.replies import Accepted, MoveRecord, MoveResult
from feeder.errors import InputError, MoveFailed


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--socket", type=Path, default=None, help=f"daemon socket (default {default_socket_path()})"
    )
    parser.add_argument(
        "--timeout",
        type=positive_float,
        default=DEFAULT_TIMEOUT_S,
        metavar="SECONDS",
        help=f"give up (exit 3) when the daemon does not answer a request or "
        f"heartbeat within SECONDS; a move may take longer "
        f"(default {DEFAULT_TIMEOUT_S:g})",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def register(subparsers: argparse._SubParsersAction) -> None:
    move = subparsers.add_parser("move", help="move the part to TARGET_M (or by --by DELTA_M)")
    move.add_argument(
        "target_m",
        nargs="?",
        type=length_m,
        metavar="TARGET_M",
        help="absolute target position, m; or with a unit: 150um, 150µm, 1.2mm, "
        "20nm (negative: `feeder move -- -100um`)",
    )
    move.add_argument(
        "--by",
        type=length_m,
        dest="by_m",
        metavar="DELTA_M",
        help="relative move from the current position, m; or with a unit (--by -20um)",
    )
    move.add_argument(
        "--x", type=length_m, dest="x_m", metavar="X", help="target x of the part's centre (1.2mm)"
    )
    move.add_argument(
        "--y", type=length_m, dest="y_m", metavar="Y", help="target y of the part's centre (-0.3mm)"
    )
    move.add_argument(
        "--angle",
        type=angle_rad,
        dest="angle_rad",
        metavar="ANGLE",
        help="target orientation (15deg, or rad)",
    )
    move.add_argument(
        "--part",
        type=int_in(1, 1000),
        default=1,
        metavar="ID",
        help="which part (default 1; see feeder status)",
    )
    move.add_argument(
        "--queue", action="store_true", help="wait for a running move to finish instead of being refused"
    )
    move.add_argument("--no-wait", action="store_true", help="return once the move is accepted")
    _common(move)
    move.set_defaults(handler=run_move)

    status = subparsers.add_parser("status", help="the daemon's state, position, learned steps")
    _common(status)
    status.set_defaults(handler=run_status)

    stop = subparsers.add_parser("stop", help="stop the running move (and drop queued ones)")
    _common(stop)
    stop.set_defaults(handler=run_stop)

    calibrate = subparsers.add_parser(
        "calibrate", help="learn the step sizes: bursts forward and back, both waveforms"
    )
    calibrate.add_argument(
        "--steps", type=int, default=20, help="coarse steps per direction, 2–10000 (default 20)"
    )
    _common(calibrate)
    calibrate.set_defaults(handler=run_calibrate)

    history = subparsers.add_parser("history", help="recorded moves, oldest first")
    history.add_argument("--limit", type=int, default=20, help="newest N moves, 1–100000 (default 20)")
    _common(history)
    history.set_defaults(handler=run_history)

    release = subparsers.add_parser(
        "release", help="let held parts go: later moves of other parts no longer keep them (plane)"
    )
    release.add_argument("--part", type=int, help="this part only (default: every held part)")
    _common(release)
    release.set_defaults(handler=run_release)

    shutdown = subparsers.add_parser("shutdown", help="stop the daemon (it grounds the output first)")
    _common(shutdown)
    shutdown.set_defaults(handler=run_shutdown)


def _client(args: argparse.Namespace) -> Client:
    return Client(args.socket, timeout_s=args.timeout)


def _pose(pose: tuple[float, float, float | None] | None) -> str:
    if pose is None:
        return "?"
    angle = "any angle" if pose[2] is None or math.isnan(pose[2]) else f"{math.degrees(pose[2]):.3f}°"
    return f"({pose[0] * 1e6:.2f}, {pose[1] * 1e6:.2f}) µm, {angle}"


def plane_status_lines(reply: dict[str, Any]) -> list[str]:
    """``feeder status`` of a plate driven in x, y and θ: every part's pose (and target), the
    tolerances, the travel and each axis' learned coarse step both ways."""
    lines = []
    held = {h.get("part"): h.get("pose") for h in reply.get("held") or ()}
    for part in reply.get("parts") or ():
        pose = part.get("pose")
        target = reply.get("target_pose") if reply.get("target_part") == part.get("id") else None
        hold = held.get(part.get("id"))
        turns = (
            f", θ step +{_deg(part['step_rad'])} / −{_deg(part.get('step_back_rad'))}"
            if "step_rad" in part
            else ""
        )  # each part's own: a turn depends on where the part is (what its jog moves by)
        lines.append(
            f"part {part.get('id')}: {_pose(None if pose is None else tuple(pose))}"
            + (f", moving to {_pose(tuple(target))}" if target is not None else "")
            + (f", held at {_pose(tuple(hold))}" if hold is not None else "")
            + turns
        )
    travel = reply.get("travel_m") or {}
    tolerance_rad = reply.get("tolerance_rad")
    lines.append(
        f"tolerance: ±{_um(reply.get('tolerance_m'))}"
        + (f", ±{math.degrees(tolerance_rad):.3f}°" if tolerance_rad is not None else "")
        + "".join(f"; travel {axis} [{_um(lo)}, {_um(hi)}]" for axis, (lo, hi) in travel.items())
    )
    for axis, info in (reply.get("axes") or {}).items():
        if "step_m" in info:
            steps = f"coarse step +{_um(info['step_m'])} / −{_um(info.get('step_back_m'))}"
        elif "step_rad" in info:
            back = _deg(info.get("step_back_rad"))
            steps = f"turn per step +{_deg(info['step_rad'])} / −{back} (part 1's, where it turns)"
        else:
            steps = "coarse step not learned yet"
        lines.append(f"axis {axis}: {steps}")
    return lines


def _deg(value: float | None) -> str:
    return "?" if value is None else f"{math.degrees(value):.4f}°"


def _angle_error(result: MoveResult) -> str:
    """The angle's error, or why there is none (any angle, or no reached pose)."""
    if result.error_rad is not None:
        return f"{math.degrees(result.error_rad):.3f}°"
    target = result.target_pose
    return "any angle" if target is not None and math.isnan(target[2]) else "?"


def _um(value: float | None) -> str:
    return "?" if value is None else f"{value * 1e6:.3f} µm"


def _print_result(result: MoveResult) -> None:
    if result.target_pose is not None:
        print(
            f"{result.kind} of part {result.part} {result.status}: {result.reason}; at {_pose(result.pose)}"
            f" for target {_pose(result.target_pose)} (error {_um(result.error_m)}, {_angle_error(result)}),"
            f" {result.steps} steps in {result.bursts} bursts,"
            f" {result.duration_s:.2f} s"
        )
        return
    print(
        f"{result.kind} {result.status}: {result.reason}; reached {_um(result.reached_m)}"
        + (
            ""
            if result.target_m is None
            else f" for target {_um(result.target_m)} (error {_um(result.error_m)})"
        )
        + f", {result.steps} steps{' (estimated)' if result.steps_estimated else ''} in "
        f"{result.bursts} bursts, {result.duration_s:.2f} s"
    )


def _job(args: argparse.Namespace, cmd: str, start: Callable[[Client, bool], MoveResult | Accepted]) -> int:
    """Run a move or calibration (``start(client, wait)``); 0 when it ends ``done`` (or was
    accepted with ``--no-wait``), 1 with the result printed when it ends otherwise."""
    with _client(args) as client:
        try:
            outcome, code = start(client, not getattr(args, "no_wait", False)), 0
        except MoveFailed as failed:
            outcome, code = failed.result, 1
    if isinstance(outcome, MoveResult):
        if args.json:
            print_json(outcome.raw)
        else:
            _print_result(outcome)
    elif args.json:
        print_json({"ok": True, "accepted": True, "queue_position": outcome.queue_position})
    else:
        print(
            f"{cmd} accepted"
            + (f" (queue position {outcome.queue_position})" if outcome.queue_position else "")
        )
    return code


def run_move(args: argparse.Namespace) -> int:
    pose = {k: getattr(args, k) for k in ("x_m", "y_m", "angle_rad") if getattr(args, k) is not None}
    if pose:
        if args.target_m is not None or args.by_m is not None:
            raise InputError("--x/--y/--angle", "give a pose or TARGET_M/--by, not both")
        if args.angle_rad is not None and abs(args.angle_rad) > 2 * math.pi:
            degrees = math.degrees(args.angle_rad)
            raise InputError("--angle", f"must lie within ±360° (one turn), got {degrees:g}°")
        return _job(
            args, "move", lambda c, wait: c.move_to_pose(**pose, part=args.part, queue=args.queue, wait=wait)
        )
    if (args.target_m is None) == (args.by_m is None):
        raise InputError("TARGET_M", "give TARGET_M, --by DELTA_M, or a pose (--x, --y, --angle)")
    if args.part != 1:  # TARGET_M and --by move part 1: part 1 moved when part 2 was asked for
        raise InputError("--part", "TARGET_M and --by move part 1 along x; move another with --x/--y/--angle")
    if args.by_m is not None:
        return _job(args, "move", lambda c, wait: c.move_by(args.by_m, queue=args.queue, wait=wait))
    return _job(args, "move", lambda c, wait: c.move_to(args.target_m, queue=args.queue, wait=wait))


def run_calibrate(args: argparse.Namespace) -> int:
    if not 2 <= args.steps <= 10_000:
        raise InputError("--steps", "must be in [2, 10000]")
    return _job(args, "calibrate", lambda c, wait: c.calibrate(args.steps, wait=wait))


def run_stop(args: argparse.Namespace) -> int:
    with _client(args) as client:
        stopped = client.stop()
    if args.json:
        print_json({"stopped": stopped.stopped, "dequeued": stopped.dequeued})
    else:
        print("stopped the running move (or camera calibration)" if stopped.stopped else "nothing was moving")
    return 0


def run_release(args: argparse.Namespace) -> int:
    if args.part is not None and args.part < 1:
        raise InputError("--part", f"must be a part id ≥ 1, got {args.part}")
    with _client(args) as client:
        released = client.release(args.part)
    if args.json:
        print_json({"released": released})
    else:
        print(f"released part {', '.join(map(str, released))}" if released else "no part was held")
    return 0


def run_shutdown(args: argparse.Namespace) -> int:
    with _client(args) as client:
        client.shutdown(wait=True)
    if args.json:
        print_json({"shutting_down": True, "stopped": True})
    else:
        print("the daemon stopped")
    return 0


def run_status(args: argparse.Namespace) -> int:
    with _client(args) as client:
        status = client.status()
    reply = dict(status.raw)
    reply.pop("ok", None)
    if args.json:
        print_json(reply)
        return 0
    print(f"state: {status.state}" + (f" ({status.fault})" if status.fault else ""))
    if reply.get("camera_moves"):
        now = reply.get("camera_moves_progress")
        print(
            "a camera calibration is moving the plate"
            + (f" ({now})" if now else "")
            + "; feeder stop ends it"
        )
    if reply.get("moves_refused"):
        print(f"moves refused: {reply['moves_refused']}")
    for key in ("sensor_noise_warning", "stack_warning"):
        if reply.get(key):
            print(f"warning: {reply[key]}")
    if len(reply.get("axes") or {}) > 1:  # a plate driven in the plane
        for line in plane_status_lines(reply):
            print(line)
    else:
        print(
            f"position: {_um(status.position_m)} ({status.position_state}; last known "
            f"{_um(status.last_known_position_m)})"
        )
        if status.target_m is not None:
            print(f"target: {_um(status.target_m)}")
        lo, hi = status.travel_limits_m
        print(f"tolerance: ±{_um(status.tolerance_m)}, travel limits [{_um(lo)}, {_um(hi)}]")
        predicted = reply.get("predicted_steps_m", {})
        for name, est in status.estimates.items():
            mode = name.split("/")[0]
            print(
                f"step {name}: {_um(est.step_m)} ± {_um(est.std_m)} after {est.steps} steps"
                + (f" (predicted {_um(predicted[mode])})" if mode in predicted else "")
            )
    if "sensor_noise_m" in reply:
        seen = reply.get("sensor_noise_seen_m")
        print(
            f"sensor noise (1σ): {_um(reply['sensor_noise_m'])} configured, "
            + ("not measured yet (parts at rest)" if seen is None else f"{_um(seen)} seen at rest")
        )
    t = reply.get("timing")
    if t:
        print(
            f"loop: {t['rate_hz']:g} Hz, {t['ticks']} ticks, {t['overruns']} overruns, jitter "
            f"p50 {t['jitter_p50_s'] * 1e3:.3f} ms, p99 {t['jitter_p99_s'] * 1e3:.3f} ms, max "
            f"{t['jitter_max_s'] * 1e3:.3f} ms"
            + (" (real-time priority)" if t.get("scheduling") == "fifo" else "")
        )
        if t.get("decision_max_s"):
            print(
                f"navigator (off the tick): last decision {t['decision_last_s'] * 1e3:.1f} ms, "
                f"longest {t['decision_max_s'] * 1e3:.1f} ms"
            )
        if t.get("collections"):
            print(
                f"garbage collections (in the tick's slack): {t['collections']}, "
                f"longest {t['collection_max_s'] * 1e3:.2f} ms"
            )
        if t.get("quiet_holds"):
            print(f"requests that stood back for the tick: {t['quiet_holds']}")
    if reply.get("interrupted_moves"):
        print(f"interrupted moves (daemon was killed): {reply['interrupted_moves']}")
    return 0


def run_history(args: argparse.Namespace) -> int:
    if not 1 <= args.limit <= 100_000:
        raise InputError("--limit", "must be in [1, 100000]")
    with _client(args) as client:
        moves = client.history(args.limit)
    if args.json:
        print_json({"moves": [m.raw for m in moves]})
        return 0
    for m in moves:
        print(history_line(m))
    return 0


def history_line(m: MoveRecord) -> str:
    """One recorded move as ``feeder history`` prints it: along x, or a part's poses in the plane."""
    pose = m.raw.get("target_pose")
    if pose is None:
        where = f"target {_um(m.target_m):>14} reached {_um(m.reached_m):>14} error {_um(m.error_m):>11}"
    else:
        reached, error_rad = m.raw.get("reached_pose"), m.raw.get("error_rad")
        where = (
            f"part {m.raw.get('part', 1)} target {_pose(tuple(pose))} reached "
            f"{_pose(None if reached is None else tuple(reached))} error {_um(m.error_m)}, {_deg(error_rad)}"
        )
    return (
        f"#{m.id:<5} {m.status:<11} {where} steps {m.steps:>5}"
        + (" (estimated)" if m.steps_estimated else "")
        + (f"  {m.reason}" if m.status != "done" else "")
    )
