"""``feeder move|status|stop|calibrate|history``: clients of the running daemon's socket."""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path
from typing import Any

from feeder.cli.output import print_json
from feeder.daemon.client import Client, DaemonUnavailable
from feeder.daemon.config import default_socket_path
from feeder.errors import InputError


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of metres, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--socket", type=Path, default=None,
                        help=f"daemon socket (default {default_socket_path()})")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def register(subparsers: argparse._SubParsersAction) -> None:
    move = subparsers.add_parser("move", help="move the part to TARGET_M (or by --by DELTA_M)")
    move.add_argument("target_m", nargs="?", type=_finite, metavar="TARGET_M",
                      help="absolute target position, m")
    move.add_argument("--by", type=_finite, dest="by_m", metavar="DELTA_M",
                      help="relative move from the current position, m")
    move.add_argument("--queue", action="store_true",
                      help="wait for a running move to finish instead of being refused")
    move.add_argument("--no-wait", action="store_true", help="return once the move is accepted")
    # let "-1e-4" be a number, not an option (argparse only knows "-1" and "-.5" forms)
    move._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")
    _common(move)
    move.set_defaults(handler=run_move)

    status = subparsers.add_parser("status", help="the daemon's state, position, learned steps")
    _common(status)
    status.set_defaults(handler=run_status)

    stop = subparsers.add_parser("stop", help="stop the running move (and drop queued ones)")
    _common(stop)
    stop.set_defaults(handler=run_stop)

    calibrate = subparsers.add_parser(
        "calibrate", help="learn the step sizes: bursts forward and back, both waveforms")
    calibrate.add_argument("--steps", type=int, default=20, help="coarse steps per direction")
    _common(calibrate)
    calibrate.set_defaults(handler=run_calibrate)

    history = subparsers.add_parser("history", help="recorded moves, oldest first")
    history.add_argument("--limit", type=int, default=20, help="newest N moves")
    _common(history)
    history.set_defaults(handler=run_history)


def _request(args: argparse.Namespace, cmd: str, **fields: Any) -> dict[str, Any]:
    path = args.socket or default_socket_path()
    try:
        with Client(path) as client:
            return client.request(cmd, **fields)
    except DaemonUnavailable as err:
        raise InputError("--socket", str(err)) from None


def _um(value: float | None) -> str:
    return "?" if value is None else f"{value * 1e6:.3f} µm"


def _print_result(result: dict[str, Any]) -> None:
    print(f"{result['kind']} {result['status']}: {result['reason']}; reached "
          f"{_um(result['reached_m'])}"
          + ("" if result["target_m"] is None else
             f" for target {_um(result['target_m'])} (error {_um(result['error_m'])})")
          + f", {result['steps']} steps in {result['bursts']} bursts, {result['duration_s']:.2f} s")


def _job(args: argparse.Namespace, cmd: str, **fields: Any) -> int:
    reply = _request(args, cmd, wait=not getattr(args, "no_wait", False), **fields)
    if "result" not in reply:
        if not reply.get("ok"):
            raise InputError(cmd, str(reply.get("error")))
        if args.json:
            print_json(reply)
        else:
            print(f"{cmd} accepted" + (f" (queue position {reply['queue_position']})"
                                       if reply.get("queue_position") else ""))
        return 0
    if args.json:
        print_json(reply["result"])
    else:
        _print_result(reply["result"])
    return 0 if reply["ok"] else 1


def run_move(args: argparse.Namespace) -> int:
    if (args.target_m is None) == (args.by_m is None):
        raise InputError("TARGET_M", "give either TARGET_M or --by DELTA_M")
    fields: dict[str, Any] = {"queue": args.queue}
    if args.by_m is not None:
        fields["by_m"] = args.by_m
    else:
        fields["target_m"] = args.target_m
    return _job(args, "move", **fields)


def run_calibrate(args: argparse.Namespace) -> int:
    if not 2 <= args.steps <= 10_000:
        raise InputError("--steps", "must be in [2, 10000]")
    return _job(args, "calibrate", steps=args.steps)


def run_stop(args: argparse.Namespace) -> int:
    reply = _request(args, "stop")
    if args.json:
        print_json({"stopped": reply.get("stopped"), "dequeued": reply.get("dequeued")})
    else:
        print("stopped the running move" if reply.get("stopped") else "nothing was moving")
    return 0


def run_status(args: argparse.Namespace) -> int:
    reply = _request(args, "status")
    reply.pop("ok", None)
    if args.json:
        print_json(reply)
        return 0
    print(f"state: {reply['state']}" + (f" ({reply['fault']})" if reply.get("fault") else ""))
    print(f"position: {_um(reply['position_m'])} ({reply['position_state']}; last known "
          f"{_um(reply['last_known_position_m'])})")
    if reply.get("target_m") is not None:
        print(f"target: {_um(reply['target_m'])}")
    lo, hi = reply["travel_limits_m"]
    print(f"tolerance: ±{_um(reply['tolerance_m'])}, travel limits [{_um(lo)}, {_um(hi)}]")
    for name, est in reply["estimates"].items():
        predicted = reply["predicted_steps_m"][name.split("/")[0]]
        print(f"step {name}: {_um(est['step_m'])} ± {_um(est['std_m'])} after {est['steps']} steps"
              f" (predicted {_um(predicted)})")
    t = reply["timing"]
    print(f"loop: {t['rate_hz']:g} Hz, {t['ticks']} ticks, {t['overruns']} overruns, jitter p50 "
          f"{t['jitter_p50_s'] * 1e3:.3f} ms, p99 {t['jitter_p99_s'] * 1e3:.3f} ms, max "
          f"{t['jitter_max_s'] * 1e3:.3f} ms")
    if reply.get("interrupted_moves"):
        print(f"interrupted moves (daemon was killed): {reply['interrupted_moves']}")
    return 0


def run_history(args: argparse.Namespace) -> int:
    if not 1 <= args.limit <= 100_000:
        raise InputError("--limit", "must be in [1, 100000]")
    reply = _request(args, "history", limit=args.limit)
    if not reply.get("ok"):
        raise InputError("--limit", str(reply.get("error")))
    if args.json:
        print_json({"moves": reply["moves"]})
        return 0
    for m in reply["moves"]:
        print(f"#{m['id']:<5} {m['status']:<11} target {_um(m['target_m']):>14} reached "
              f"{_um(m['reached_m']):>14} error {_um(m['error_m']):>11} steps {m['steps']:>5}"
              + (f"  {m['reason']}" if m["status"] != "done" else ""))
    return 0
