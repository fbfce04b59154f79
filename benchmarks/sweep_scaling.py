"""Sweep scaling: the same plant-model sweep serially and on a local Dask cluster (one worker per core).

Points: 2048 current-limited sawtooths on the full plant (amplifier, stack,
exact stick-slip), 150 periods each with 3 % step scatter: 8 frequencies
20–400 Hz × 8 amplitudes × two parts × 16 scatter seeds, chunks of 50 points
(quick: 256 points in chunks of 20).  Headline ``ratio`` = serial time / Dask time, on
workers that have imported the package and loaded the compiled kernels
(:func:`feeder.sweep.warm_up`; the compute speed-up, goal ≥ 1.7 on 2 cores);
``ratio_with_startup`` counts the cluster's start and the warm-up too.  All
runs' results are checked equal, value for value.

The workers run with :data:`feeder.sweep.WORKER_MALLOC_ENV` (glibc malloc
thresholds; Dask's own setting costs +47 % CPU per chunk in page faults), and
so that the comparison stays fair the serial run in this process gets the same
settings through ``mallopt`` (``serial_has_worker_malloc``).

The machine may be shared.  Other jobs' load changes the speed of a run
two-fold within a minute, so serial and Dask runs are interleaved (S, D, S, D)
and the best of each kept, and the run reports what the machine gave it:
``others_busy_cores`` (CPU used by other processes over a second before the
runs, from /proc/stat), ``serial_cpu_per_wall`` (≈ 1: the serial run had a
core to itself and is single-threaded), and ``capacity`` — a pure-Python loop
timed alone in this process, then on every worker at once: the speed-up a
perfectly parallel job could reach now (2 on an idle 2-core machine).
``efficiency`` = ratio / capacity is the sweep's share of it.  ``cpu_ratio``
projects the speed-up on free cores from CPU times, not wall times: serial
CPU over the Dask run's bound (its busiest worker's CPU, or all its CPU —
workers, scheduler, client and Parquet writes — over the cores); it shows
whether the work splits evenly and the overhead is small when the machine is
too busy for the wall-clock ratio to say so.
"""

from __future__ import annotations

import ctypes
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from feeder.sweep import WORKER_MALLOC_ENV, local_cluster, run_sweep, warm_up
from feeder.sweep_spec import DEFAULTS, SweepSettings, SweepSpec

PROBE_LOOPS = 10_000_000
PERIODS = 150
"""Periods per point: enough plant work per chunk that the driver's share (scheduler, client,
Parquet writes: ~1.3 s of CPU for the whole sweep, whatever the periods) stays small on
2 cores; at 50 periods it alone held the projected speed-up to 1.66."""


def spec(quick: bool) -> SweepSpec:
    freqs = [float(f) for f in np.geomspace(20.0, 400.0, 8)]
    volts = [60.0, 80.0, 100.0, 120.0, 140.0, 160.0, 180.0, 200.0]
    seeds = range(2 if quick else 16)
    parts = ("300x300x50", "500x500x50")
    points = [{**DEFAULTS, "frequency_hz": f, "amplitude_vpp": v, "part": p, "scatter": 0.03, "seed": s}
              for f in freqs for v in volts for p in parts for s in seeds]  # fmt: skip
    return SweepSpec(SweepSettings(model="plant", periods=PERIODS), points, chunk_size=20 if quick else 50)


def probe(loops: int = PROBE_LOOPS) -> float:
    """Wall time (s) of a fixed pure-Python loop: the CPU a process gets now."""
    start = time.perf_counter()
    total = 0
    for i in range(loops):
        total += i * i
    return time.perf_counter() - start


def capacity(client: Any) -> float:
    """Σ over workers of (loop alone here) / (loop on that worker while all run it)."""
    alone = min(probe() for _ in range(2))
    together = client.run(probe)
    return sum(alone / t for t in together.values())


def cpu_s() -> float:
    """CPU time (s) this process has used (run on each worker with ``client.run``)."""
    return time.process_time()


def same_allocator_here() -> bool:
    """Give this process (the serial run) the workers' malloc settings, with glibc's mallopt."""
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # glibc's malloc.h
    return bool(libc.mallopt(m_mmap_threshold, WORKER_MALLOC_ENV["MALLOC_MMAP_THRESHOLD_"]) and
                libc.mallopt(m_trim_threshold, WORKER_MALLOC_ENV["MALLOC_TRIM_THRESHOLD_"]))  # fmt: skip


def others_busy_cores(seconds: float = 1.0) -> float:
    """Cores' worth of CPU used by every process on the machine over ``seconds`` (we are idle)."""

    def sample() -> tuple[int, int]:
        fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
        return sum(fields), fields[3] + fields[4]  # total, idle + iowait

    t0, i0 = sample()
    time.sleep(seconds)
    t1, i1 = sample()
    return (os.cpu_count() or 1) * (1 - (i1 - i0) / max(t1 - t0, 1))


def run(quick: bool = False) -> dict[str, object]:
    from dask.distributed import Client

    sweep = spec(quick)
    workers = os.cpu_count() or 1
    same_allocator = same_allocator_here()
    others = others_busy_cores()
    load_before = os.getloadavg()[0]
    serial_times, serial_cpu, dask_times, capacities = [], [], [], []
    driver_cpu: list[float] = []
    worker_cpu: list[list[float]] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        t0 = time.perf_counter()
        cluster = local_cluster(workers)
        client = Client(cluster)
        try:
            client.run(warm_up, sweep.settings)
            startup_s = time.perf_counter() - t0
            warm_up(sweep.settings)
            capacities.append(capacity(client))
            for k in range(2):  # interleaved: S, D, S, D (fresh output each time: nothing cached)
                t0, c0 = time.perf_counter(), time.process_time()
                run_sweep(sweep, folder / f"serial{k}.parquet", serial=True)
                serial_times.append(time.perf_counter() - t0)
                serial_cpu.append(time.process_time() - c0)
                before, c0, t0 = client.run(cpu_s), time.process_time(), time.perf_counter()
                run_sweep(sweep, folder / f"dask{k}.parquet", scheduler=cluster.scheduler_address)
                dask_times.append(time.perf_counter() - t0)
                driver_cpu.append(time.process_time() - c0)
                after = client.run(cpu_s)
                worker_cpu.append([after[w] - before[w] for w in before])
            capacities.append(capacity(client))
        finally:
            client.close()
            cluster.close()
        frames = [
            pd.read_parquet(folder / f"{kind}{k}.parquet") for kind in ("serial", "dask") for k in range(2)
        ]
        same = all(frames[0].equals(f) for f in frames[1:])
    best = int(np.argmin(serial_times))
    serial_s, dask_s = serial_times[best], min(dask_times)
    ratio = serial_s / dask_s
    # on `workers` free cores a Dask run lasts at least its busiest worker's CPU time, and at least
    # all its CPU (workers + this process: scheduler, client, Parquet writes) spread over the cores
    k = int(np.argmin(dask_times))
    dask_cpu_bound = max(max(worker_cpu[k]), (sum(worker_cpu[k]) + driver_cpu[k]) / workers)
    return {
        "ratio": ratio,
        "ratio_with_startup": serial_s / (dask_s + startup_s),
        "capacity": min(capacities),
        "capacity_runs": capacities,
        "efficiency": ratio / max(capacities),
        "workers": workers,
        "points": len(sweep.points),
        "chunks": len(sweep.chunks()),
        "serial_s": serial_s,
        "dask_s": dask_s,
        "serial_runs_s": serial_times,
        "dask_runs_s": dask_times,
        "serial_cpu_per_wall": serial_cpu[best] / serial_s,
        "serial_cpu_s": serial_cpu[best],
        "dask_worker_cpu_s": worker_cpu[k],
        "dask_driver_cpu_s": driver_cpu[k],
        "cpu_ratio": serial_cpu[best] / dask_cpu_bound,
        "cluster_startup_s": startup_s,
        "identical_results": same,
        "serial_has_worker_malloc": same_allocator,
        "others_busy_cores": others,
        "load_average_1min_before": load_before,
        "load_average_1min": os.getloadavg()[0],
    }
