"""Start-up time of ``feeder --help`` and ``feeder status`` (against a dead socket, exit 3).

Each is a fresh ``python -m feeder ...`` process, timed from spawn to exit,
interleaved with the floor ``python -c pass`` so both see the same machine load.
The target is ≤ 0.5 s each (issue #11); ratio = floor median / slower median.

    python benchmarks/cli_start.py [--json] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 0.5


def _time(command: list[str], expect_code: int) -> float:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p),
    }
    start = time.perf_counter()
    done = subprocess.run(
        command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, check=False
    )
    elapsed = time.perf_counter() - start
    if done.returncode != expect_code:
        raise RuntimeError(
            f"{' '.join(command)}: exit {done.returncode}, expected {expect_code}: {done.stderr.strip()}"
        )
    return elapsed


def run(quick: bool) -> dict[str, object]:
    rounds = 5 if quick else 20
    dead_socket = str(Path(tempfile.gettempdir()) / f"feeder-bench-{os.getpid()}" / "none.sock")
    commands = {
        "floor": ([sys.executable, "-c", "pass"], 0),
        "help": ([sys.executable, "-m", "feeder", "--help"], 0),
        "status": ([sys.executable, "-m", "feeder", "status", "--socket", dead_socket], 3),
    }
    times: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(rounds):
        for name, (command, code) in commands.items():
            times[name].append(_time(command, code))
    median = {name: statistics.median(t) for name, t in times.items()}
    slower = max(median["help"], median["status"])
    return {
        "ratio": median["floor"] / slower,
        "runs": rounds,
        "help_median_s": median["help"],
        "help_max_s": max(times["help"]),
        "status_median_s": median["status"],
        "status_max_s": max(times["status"]),
        "floor_median_s": median["floor"],
        "target_s": TARGET_S,
        "within_target": slower <= TARGET_S,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--quick", action="store_true", help="fewer runs")
    args = parser.parse_args()
    result = run(quick=args.quick)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in result.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
