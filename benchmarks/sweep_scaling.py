"""Sweep scaling: the same plant-model sweep serially and on a local Dask cluster (one worker per core).

Points: current-limited sawtooths on the full plant (amplifier, stack, exact
stick-slip), 5 periods each, frequencies 50–400 Hz × amplitudes × two parts ×
scatter seeds; chunks of 20 points.  Headline ``ratio`` = serial time / Dask
time on a cluster whose workers have already imported the package (the
compute speed-up; goal ≥ 1.7 on 2 cores); ``ratio_with_startup`` counts the
cluster's start and the workers' imports too.  Both runs' results are checked
equal.  The machine may be shared, and other jobs' load changes the speed of
a run two-fold within a minute: serial and Dask runs are interleaved
(S, D, S, D) and the best of each kept; the load average is reported too.
"""

from __future__ import annotations

import importlib
import os
import tempfile
import time
from pathlib import Path

import pandas as pd

from feeder.sweep import DEFAULTS, SweepSettings, SweepSpec, run_sweep


def spec(quick: bool) -> SweepSpec:
    freqs = [50.0, 75.0, 100.0, 150.0, 200.0, 300.0, 400.0]
    volts = [60.0, 80.0, 100.0, 120.0, 140.0, 160.0, 180.0, 200.0]
    seeds = range(2 if quick else 6)
    parts = ("300x300x50", "500x500x50")
    points = [{**DEFAULTS, "frequency_hz": f, "amplitude_vpp": v, "part": p, "scatter": 0.03, "seed": s}
              for f in freqs for v in volts for p in parts for s in seeds]  # fmt: skip
    return SweepSpec(SweepSettings(model="plant", periods=5), points, chunk_size=20)


def run(quick: bool = False) -> dict[str, object]:
    from dask.distributed import Client, LocalCluster

    sweep = spec(quick)
    workers = os.cpu_count() or 1
    serial_times, dask_times = [], []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        t0 = time.perf_counter()
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None)  # fmt: skip
        client = Client(cluster)
        try:
            client.run(importlib.import_module, "feeder.sweep")
            startup_s = time.perf_counter() - t0
            for k in range(2):  # interleaved: S, D, S, D (fresh output each time: nothing cached)
                t0 = time.perf_counter()
                run_sweep(sweep, folder / f"serial{k}.parquet", serial=True)
                serial_times.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                run_sweep(sweep, folder / f"dask{k}.parquet", scheduler=cluster.scheduler_address)
                dask_times.append(time.perf_counter() - t0)
        finally:
            client.close()
            cluster.close()
        same = pd.read_parquet(folder / "serial0.parquet").equals(pd.read_parquet(folder / "dask1.parquet"))
    serial_s, dask_s = min(serial_times), min(dask_times)
    return {
        "ratio": serial_s / dask_s,
        "ratio_with_startup": serial_s / (dask_s + startup_s),
        "workers": workers,
        "points": len(sweep.points),
        "serial_s": serial_s,
        "dask_s": dask_s,
        "serial_runs_s": serial_times,
        "dask_runs_s": dask_times,
        "cluster_startup_s": startup_s,
        "identical_results": same,
        "load_average_1min": os.getloadavg()[0],
    }
