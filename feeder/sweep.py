"""Parameter sweeps of waveform × part × surface × scatter seed, serial or on Dask, resumable.

The spec and its points: :mod:`feeder.sweep_spec`.

Resuming: the points are cut into chunks in order; each chunk is a Parquet
part file in ``<out>.parts/`` named by a hash of its inputs and the settings, so
a restarted sweep recomputes only the chunks without a part file.  The result
is the parts concatenated in point order, written atomically; the parts folder
is made only when the first chunk is written (a sweep that fails before any
work, e.g. an unreachable scheduler, leaves nothing behind).  Every point's
computation depends only on its own row (seeded), so a Dask run and a serial
run give identical numbers.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from feeder.contact.breakaway import contact
from feeder.errors import FeederError, InputError
from feeder.parts import Part, Support
from feeder.plant.plant import run_waveform
from feeder.plant.steady_state import ideal_steady_steps, steady_start
from feeder.plant.stick_slip import Friction
from feeder.surface.parameters import DEFAULT_SURFACE, SurfaceParameters, load_surface
from feeder.sweep_spec import DEFAULTS, OUTPUTS, SweepSettings, SweepSpec, chunk_key
from feeder.waveform import Waveform

if TYPE_CHECKING:
    from dask.distributed import Client, LocalCluster

log = logging.getLogger(__name__)

SCHEDULER_CONNECT_TIMEOUT_S = 10.0
"""How long to try connecting to a ``scheduler`` address (Dask's default: 30 s)."""


class SchedulerUnreachable(FeederError):
    """No Dask scheduler answered at ``address`` within :data:`SCHEDULER_CONNECT_TIMEOUT_S`."""

    def __init__(self, address: str, message: str) -> None:
        super().__init__(f"{address}: {message}")
        self.address = address
        self.message = message


def _surface(label: str) -> SurfaceParameters:
    return DEFAULT_SURFACE if label == "embedded" else load_surface(Path(label))


def _waveform(row: dict[str, Any]) -> Waveform:
    shape = row["flyback_shape"]
    flyback = None if shape == "current-limited" else row["flyback_s"]
    return Waveform(frequency_hz=row["frequency_hz"], amplitude_vpp=row["amplitude_vpp"],
                    flyback_shape=shape, flyback_s=flyback)  # fmt: skip


@lru_cache(maxsize=1024)
def breakaway_accel_m_s2(part: Part, support: Support, surface: SurfaceParameters, tau_pa: float) -> float:
    """a_s = τ·A_r/m (m/s²) of the contact model, computed once per process for each input.

    The Greenwood–Williamson solve costs ~25 ms, a 5-period plant point ~1 ms:
    computed per chunk it was three quarters of a sweep's work.  Memoised on
    the values (the surface's parameters, not its file name), so a worker
    solves each contact once for all its chunks and results do not change.
    """
    return contact(part, support, surface, tau_pa).breakaway_accel_m_s2


def evaluate_chunk(settings: SweepSettings, rows: list[dict[str, Any]]) -> pd.DataFrame:
    """Evaluate one chunk: the input rows with the output columns (runs on a Dask worker)."""
    results: list[dict[str, Any]] = [dict(row) for row in rows]
    for out in results:
        out.update({name: math.nan for name in OUTPUTS})
        out["error"] = ""
        try:
            out["breakaway_accel_m_s2"] = breakaway_accel_m_s2(
                Part.parse(out["part"]), Support.parse(out["support"]), _surface(out["surface"]),
                out["tau_pa"])  # fmt: skip
            settings.amplifier.check(_waveform(out))
            if settings.model == "ideal" and out["scatter"] > 0:
                raise InputError("scatter", 'the ideal model has no scatter (use model = "plant")')
        except FeederError as err:
            out["error"] = str(err)
    if settings.model == "plant":
        for out in results:
            if not out["error"]:
                try:
                    _plant_point(settings, out)
                except FeederError as err:
                    out["error"] = str(err)
    else:
        _ideal_points(settings, [out for out in results if not out["error"]])
    for out in results:
        out["speed_m_s"] = out["step_mean_m"] * out["frequency_hz"]
    return pd.DataFrame(results, columns=[*rows[0].keys(), *OUTPUTS])


def warm_up(settings: SweepSettings) -> None:
    """Evaluate one default point: imports and loads the compiled plant kernels (~0.5–1 s once).

    ``client.run(warm_up, settings)`` readies every Dask worker before timing a sweep.
    """
    evaluate_chunk(settings, [dict(DEFAULTS)])


def _plant_point(settings: SweepSettings, out: dict[str, Any]) -> None:
    friction = Friction(out["breakaway_accel_m_s2"], out["kinetic_ratio"])
    run = run_waveform(friction, _waveform(out), settings.periods, settings.amplifier, settings.stack,
                       scatter=out["scatter"], seed=out["seed"])  # fmt: skip
    steps = run.steps_m
    if out["scatter"] > 0:  # steps scatter by design: every period counts, not judged
        out["transient_periods"], out["steady"] = 0, None
    else:
        start, settled = steady_start(steps)
        out["transient_periods"], out["steady"] = int(start[0]), bool(settled[0])
        steps = steps[start[0] :]
    out["step_mean_m"] = float(np.mean(steps))
    out["step_std_m"] = float(np.std(steps, ddof=1)) if steps.size > 1 else 0.0
    out["slip_fraction"] = run.slip_fraction


def _ideal_points(settings: SweepSettings, rows: list[dict[str, Any]]) -> None:
    """Ideal plate (no amplifier dynamics, no scatter), all rows of a flyback shape at once."""
    stack = settings.stack
    for shape in ("linear", "half-cosine"):
        group = [r for r in rows if r["flyback_shape"] == shape or
                 (shape == "linear" and r["flyback_shape"] == "current-limited")]  # fmt: skip
        if not group:
            continue
        volts = np.array([r["amplitude_vpp"] for r in group])
        freq = np.array([r["frequency_hz"] for r in group])
        t_f = np.array([r["flyback_s"] for r in group])
        stroke = stack.gain_m_per_v * volts
        limited = np.array([r["flyback_shape"] == "current-limited" for r in group])
        if limited.any():  # the current limit sets a linear flyback over part of the swing
            t_cl, fraction = settings.amplifier.current_limited_flyback(volts, freq, stack.capacitance_f)
            t_f = np.where(limited, t_cl, t_f)
            stroke = np.where(limited, stroke * fraction, stroke)
        a_s = np.array([r["breakaway_accel_m_s2"] for r in group])
        ratio = np.array([r["kinetic_ratio"] for r in group])
        found = ideal_steady_steps(stroke, freq, t_f, shape, a_s, ratio, settings.periods)
        for k, r in enumerate(group):
            r["step_mean_m"], r["step_std_m"] = float(found.step_m[k]), float(found.std_m[k])
            r["transient_periods"], r["steady"] = int(found.transient_periods[k]), bool(found.settled[k])
            r["slip_fraction"] = float(found.slip_fraction[k])


def _write_parquet(frame: pd.DataFrame, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    frame.to_parquet(tmp, index=False)
    tmp.replace(path)


def parts_dir(out: Path) -> Path:
    """Where the chunk part files of ``out`` live."""
    return out.with_name(out.name + ".parts")


@dataclass(frozen=True)
class SweepReport:
    """What a run did: points, chunks, how many were computed now and how many were already done,
    and how many points could not run (``failed``; ``first_error``: the lowest such point's error)."""

    points: int
    chunks: int
    computed: int
    cached: int
    path: Path
    failed: int = 0
    first_error: str = ""


def run_sweep(
    spec: SweepSpec,
    out: Path | str,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    serial: bool = False,
    progress: Callable[[int, int, int], None] | None = None,
) -> SweepReport:
    """Evaluate every chunk without a part file, then write ``out`` (Parquet, point order).

    serial: in this process; scheduler: an existing Dask scheduler's address
    (``tcp://host:8786``); otherwise a local Dask cluster of ``workers``
    processes (default: one per core) bound to 127.0.0.1.
    progress(done, total, cached) is called as chunks finish.  A ``scheduler`` that does not
    answer is :class:`SchedulerUnreachable` (a malformed address: :class:`InputError`), raised
    before anything is written.
    """
    out = Path(out)
    folder = parts_dir(out)
    chunks = spec.chunks()
    offsets = np.cumsum([0] + [len(c) for c in chunks])
    keys = [chunk_key(spec.settings, rows) for rows in chunks]
    files = [folder / f"chunk-{key}.parquet" for key in keys]
    todo = [i for i, f in enumerate(files) if not f.exists()]
    cached = len(chunks) - len(todo)
    say = progress or (lambda done, total, skipped: None)
    with _dask_client(workers, scheduler, serial, needed=bool(todo)) as client:  # connects first
        say(cached, len(chunks), cached)
        done = cached
        for index, frame in _evaluate(spec.settings, [chunks[i] for i in todo], todo, client):
            frame.insert(0, "point", np.arange(offsets[index], offsets[index + 1]))
            folder.mkdir(parents=True, exist_ok=True)
            _write_parquet(frame, files[index])
            done += 1
            say(done, len(chunks), cached)
    result = pd.concat([pd.read_parquet(f) for f in files], ignore_index=True)
    _write_parquet(result, out)
    errors = result["error"][result["error"] != ""]
    first = str(errors.iloc[0]) if len(errors) else ""
    if len(errors):
        log.info("%d of %d points could not run; the first: %s", len(errors), len(result), first)
    return SweepReport(len(spec.points), len(chunks), len(todo), cached, out, len(errors), first)


WORKER_MALLOC_ENV = {"MALLOC_MMAP_THRESHOLD_": 32 * 2**20, "MALLOC_TRIM_THRESHOLD_": 64 * 2**20}
"""glibc malloc settings of local workers (bytes): allocations up to 32 MiB from the heap, up to
64 MiB of it kept free.  Dask's nanny sets ``MALLOC_TRIM_THRESHOLD_=65536``, which switches off
glibc's dynamic mmap threshold: every MB-sized temporary of a plant point is then a fresh mmap
paid for in page faults — measured 2× the page faults and +47 % CPU per chunk against a plain
process, and −30 % with these values (glibc's own dynamic limits on 64-bit)."""


def local_cluster(workers: int) -> LocalCluster:
    """A local Dask cluster: ``workers`` single-threaded processes on 127.0.0.1, no dashboard.

    Processes, not threads: a plant point holds the GIL.  The workers get
    :data:`WORKER_MALLOC_ENV` (it must be set before they start) and Dask's
    one BLAS/OpenMP thread each.
    """
    import dask
    from dask.distributed import LocalCluster

    environ = {**dask.config.get("distributed.nanny.pre-spawn-environ"), **WORKER_MALLOC_ENV}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address=None)  # fmt: skip


@contextmanager
def _dask_client(
    workers: int | None, scheduler: str | None, serial: bool, needed: bool
) -> Iterator[Client | None]:
    """A client of the ``scheduler`` or of a local cluster, closed on exit; None when serial or not needed."""
    if serial or not needed:
        yield None
        return
    from dask.distributed import Client

    if scheduler:
        client = _connect(scheduler)
        cluster = None
    else:
        cluster = local_cluster(workers or os.cpu_count() or 1)
        client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _evaluate(
    settings: SweepSettings,
    chunks: list[list[dict[str, Any]]],
    indices: list[int],
    client: Client | None,
) -> Iterator[tuple[int, pd.DataFrame]]:
    """(chunk index, frame) as each chunk finishes (in any order on Dask; client None: serially)."""
    if client is None:
        for index, rows in zip(indices, chunks, strict=True):
            yield index, evaluate_chunk(settings, rows)
        return
    from dask.distributed import as_completed

    futures = {client.submit(evaluate_chunk, settings, rows, pure=False): index
               for index, rows in zip(indices, chunks, strict=True)}  # fmt: skip
    for future in as_completed(futures):
        yield futures[future], future.result()


def _connect(address: str) -> Client:
    """A client of the Dask scheduler at ``address``, tried for :data:`SCHEDULER_CONNECT_TIMEOUT_S`."""
    from dask.distributed import Client

    try:
        return Client(address, timeout=SCHEDULER_CONNECT_TIMEOUT_S)
    except ValueError as err:  # distributed: unknown scheme, missing port, bad host
        raise InputError("scheduler", f"{address!r}: {err}") from None
    except OSError as err:  # distributed: "Timed out trying to connect …" (refused, no route, no host)
        raise SchedulerUnreachable(address, str(err) or type(err).__name__) from None


def plot_sweep(results: Path | str, png: Path | str) -> None:
    """Standard views of a result file: step vs frequency, vs flyback, and the scatter bands."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from feeder.files import save_figure

    frame = pd.read_parquet(results)
    ok = frame[frame["error"] == ""]
    um = 1e6
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    ax = axes[0]
    for shape, group in ok.groupby("flyback_shape"):
        ax.scatter(group["frequency_hz"], group["step_mean_m"] * um, s=8, alpha=0.6, label=str(shape))
    ax.set_xscale("log")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("mean step (µm)")
    ax.set_title("step vs frequency", fontsize=9)
    ax.legend(fontsize=8)
    ax = axes[1]
    commanded = ok[ok["flyback_shape"] != "current-limited"]
    if len(commanded):
        points = ax.scatter(commanded["flyback_s"] * 1e3, commanded["step_mean_m"] * um, s=8,
                            c=commanded["amplitude_vpp"], cmap="viridis")  # fmt: skip
        fig.colorbar(points, ax=ax, label="amplitude (Vpp)")
    ax.set_xlabel("commanded flyback (ms)")
    ax.set_ylabel("mean step (µm)")
    ax.set_title("step vs flyback (linear, half-cosine)", fontsize=9)
    ax = axes[2]
    seeds = ok.groupby(["scatter", "frequency_hz"])["step_mean_m"].agg(["mean", "std", "min", "max"])
    for scatter, band in seeds.groupby(level=0):
        f = band.index.get_level_values(1)
        ax.plot(f, band["mean"] * um, label=f"scatter {scatter:g}")
        ax.fill_between(f, band["min"] * um, band["max"] * um, alpha=0.25)
    ax.set_xscale("log")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("mean step (µm), band: min–max over the rest")
    ax.set_title("scatter bands", fontsize=9)
    ax.legend(fontsize=8)
    fig.suptitle(f"{Path(results).name}: {len(ok)} points ({len(frame) - len(ok)} could not run)")
    fig.tight_layout()
    save_figure(fig, Path(png))
