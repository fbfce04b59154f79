"""Run the benchmarks: each prints a ratio against a baseline timed in the same run.

    python benchmarks/run.py [--json] [--quick] [NAME ...]

A benchmark is a module ``benchmarks/<name>.py`` with ``run(quick: bool) -> dict``
returning at least ``{"ratio": baseline_time / our_time}`` (higher is better)
plus its own figures.  Add its name to :data:`BENCHMARKS`.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from pathlib import Path

BENCHMARKS: tuple[str, ...] = (
    "fn_eval",
    "gw_solve",
    "gw_md_solve",
    "loop_jitter",
    "summits",
    "console_rtt",
    "tick_jitter",
    "sdo_rtt",
    "pdo_rate",
    "stickslip",
    "stickslip_half_cosine",
    "plant_realtime",
    "plant_realtime_1ms",
    "planar_period",
    "pose_planner",
    "vision_locate",
    "vision_render",
    "pose_camera",
    "http_camera",
    "pose_daemon",
    "cli_start",
    "sweep_scaling",
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", metavar="NAME", help=f"any of {', '.join(BENCHMARKS)}")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--quick", action="store_true", help="smaller sizes (smoke run)")
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in BENCHMARKS]
    if unknown:
        print(
            f"run.py: error: unknown benchmark {unknown[0]!r}; known: {', '.join(BENCHMARKS)}",
            file=sys.stderr,
        )
        return 2
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    results: dict[str, dict[str, object]] = {}
    for name in args.names or BENCHMARKS:
        if not args.json:
            print(f"running {name} ...", file=sys.stderr, flush=True)
        results[name] = importlib.import_module(name).run(quick=args.quick)
        if not args.json:
            figures = ", ".join(
                f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in results[name].items()
            )
            print(f"{name}: {figures}", flush=True)
    if args.json:
        print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
