"""``feeder sweep``: evaluate a grid or random sample of designs × parts × surfaces × seeds on Dask.

Exit codes: 0 done (some points may have failed: ``points_failed``); 1 every point
failed (the first one's error on stderr; the result file is written all the same);
2 bad input (a spec or size refused before any work); 3 the ``--scheduler`` did not
answer (nothing written).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from feeder.cli.output import print_json
from feeder.errors import InputError


def register(sub: Any) -> None:
    p = sub.add_parser("sweep", help="parameter sweep on Dask (local cluster or a scheduler), to Parquet")
    p.add_argument(
        "spec", type=Path, help="sweep spec (TOML; format: feeder/sweep_spec.py; examples: waveforms/)"
    )
    p.add_argument("--out", type=Path, required=True, help="results (Parquet); part files go beside it")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, help="local Dask cluster of N processes (default: cores)")
    where.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask scheduler, tcp://HOST:8786")
    where.add_argument("--serial", action="store_true", help="in this process, no Dask")
    p.add_argument("--plot", type=Path, nargs="?", const=True, metavar="PNG",
                   help="standard views (step vs frequency and flyback, scatter bands); "
                        "default path: OUT with .png")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if args.workers is not None and args.workers < 1:
        raise InputError("--workers", f"must be at least 1, got {args.workers}")
    if args.out.suffix.lower() != ".parquet":
        raise InputError("--out", f"expected a .parquet file, got {args.out}")
    try:
        from feeder.sweep import SchedulerUnreachable, run_sweep
        from feeder.sweep_spec import load_spec
    except ImportError as err:
        raise InputError(
            "feeder sweep", f"needs the sweep extra (pip install 'feeder[sweep]'): {err}"
        ) from None
    spec = load_spec(args.spec)
    start = time.monotonic()

    def progress(done: int, total: int, cached: int) -> None:
        width = 30
        filled = round(width * done / total) if total else width
        print(f"\rsweep [{'#' * filled}{'.' * (width - filled)}] {done}/{total} chunks "
              f"({cached} already done) {time.monotonic() - start:.1f} s",
              end="\n" if done == total else "", file=sys.stderr, flush=True)  # fmt: skip

    try:
        report = run_sweep(spec, args.out, workers=args.workers, scheduler=args.scheduler,
                           serial=args.serial, progress=progress)  # fmt: skip
    except SchedulerUnreachable as err:
        print(f"feeder sweep: scheduler unreachable: --scheduler {err}", file=sys.stderr)
        return 3
    except InputError as err:
        if err.field == "scheduler":
            raise InputError("--scheduler", err.message) from None
        raise
    all_failed = report.failed == report.points
    out: dict[str, Any] = {"path": str(report.path), "points": report.points, "chunks": report.chunks,
                           "chunks_computed": report.computed, "chunks_cached": report.cached,
                           "points_failed": report.failed, "first_error": report.first_error,
                           "elapsed_s": time.monotonic() - start}  # fmt: skip
    if args.plot and not all_failed:  # nothing to plot
        from feeder.sweep import plot_sweep

        png = args.out.with_suffix(".png") if args.plot is True else args.plot
        plot_sweep(report.path, png)
        out["plot"] = str(png)
    if args.json:
        print_json(out)
    else:
        print(f"{_count(report.points, 'point')} in {_count(report.chunks, 'chunk')} "
              f"({report.computed} computed, {report.cached} already done), "
              f"{report.failed} failed → {report.path}")  # fmt: skip
        if "plot" in out:
            print(f"plot → {out['plot']}")
    if all_failed:
        print(f"feeder sweep: failed: every point failed; the first: {report.first_error}", file=sys.stderr)
        return 1
    return 0


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"
