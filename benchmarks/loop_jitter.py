"""Control-loop tick jitter: the daemon's loop at its default rate vs a bare ``time.sleep`` loop.

Both run for 10 s (2 s with ``--quick``) at the loop's default rate, one after
the other in the same process.  The control loop runs with a sensor streaming
frames at 200 Hz through its reader thread and an amplifier that answers at
once (the loop's own overhead, not the link's).  ratio = baseline p99 jitter /
loop p99 jitter (1.0: the loop adds nothing to what the OS scheduler gives).

A third run keeps the loop busy with moves (the part never moves, so each
ends stalled after two bursts and the next starts) while every record write
(move start, end, position) takes 50 ms, as on a slow disk: ``slow_commit_*``
are its tick jitter figures (goal p99 ≤ 0.5 ms: no commit is on the tick).

Two more runs keep another thread making cyclic garbage (1000 objects every 2 ms, as a
console serving requests does; 10 of them kept among the last 2000, as recent history and
caches are) over a heap of 500 000 long-lived objects built before the loop starts (the
daemon's modules, configuration and drivers): ``collector_*`` with the
collections run in the tick's slack (the default), ``automatic_*`` with CPython collecting
wherever allocation triggers it; ``collector_ratio`` = automatic max lateness / collector max
lateness.

Two more keep an event loop on another thread answering requests, 100 at a time, back to
back (each encodes a status reply three times, yielding between: ~0.1 ms of Python a step),
and two worker threads encoding replies, as the console's thread pool does: ``requests_*``
with those threads standing back while the tick is due (``QuietWindow``: the event loop
from ``quiet_event_loop``, the workers holding before each reply, as the daemon does),
``unheld_*`` with the same threads not holding; ``requests_ratio`` = unheld p99 lateness /
requests p99 lateness.
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections import deque

import numpy as np

from feeder.daemon.control_loop import COARSE, FINE, ControlLoop, Job, LoopSettings, StepMode
from feeder.daemon.quiet_window import quiet_event_loop
from feeder.drivers.amplifier import Amplifier, AmplifierStatus, DriveSettings
from feeder.drivers.sensor import PositionSample, PositionSensor


class _StillSensor(PositionSensor):
    """A camera at 200 Hz looking at a part that does not move."""

    def __init__(self) -> None:
        self.sequence = 0
        self.next_s = time.monotonic()

    def read(self, timeout_s: float = 1.0) -> PositionSample:
        self.next_s += 0.005
        time.sleep(max(0.0, self.next_s - time.monotonic()))
        self.sequence += 1
        return PositionSample(time.monotonic(), 0.0, self.sequence)

    def close(self) -> None:
        pass


class _InstantAmplifier(Amplifier):
    def apply(self, settings: DriveSettings) -> None: ...
    def step(self, count: int) -> None: ...
    def run_continuous(self, forward: bool) -> None: ...
    def stop(self) -> None: ...
    def wait(self, timeout_s: float) -> bool:
        return True

    def ground(self) -> None: ...
    def enable(self) -> None: ...
    def status(self) -> AmplifierStatus:
        return AmplifierStatus("gnd", 100.0, 0.0, 0, False)

    def close(self) -> None: ...


def _sleep_loop(rate_hz: float, duration_s: float) -> np.ndarray:
    period = 1.0 / rate_hz
    deadline = time.monotonic() + period
    end = deadline + duration_s
    jitter = []
    while deadline < end:
        delay = deadline - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        jitter.append(time.monotonic() - deadline)
        deadline += period
    return np.array(jitter)


SLOW_COMMIT_S = 0.05
MODES = {
    COARSE: StepMode(COARSE, DriveSettings(100.0, 100.0), 3e-6, (2.5e-6, 3.5e-6)),
    FINE: StepMode(FINE, DriveSettings(100.0, 50.0), 1e-6, (0.5e-6, 1.5e-6)),
}


def _slow_write(*_: object) -> None:
    time.sleep(SLOW_COMMIT_S)


def _busy_with_slow_commits(settings: LoopSettings, duration: float) -> tuple[dict[str, float | int], int]:
    """The loop running moves back to back while every record write takes 50 ms."""
    loop = ControlLoop(_InstantAmplifier(), _StillSensor(), MODES, settings, on_position=_slow_write)
    loop.start()
    jobs = 0
    end = time.monotonic() + duration
    while time.monotonic() < end:
        job = Job("move", target_m=50e-6, on_start=_slow_write, on_done=_slow_write)
        if loop.submit(job) is None:
            jobs += 1
            job.done.wait(end - time.monotonic() + 5)
        else:
            threading.Event().wait(0.01)
    loop.shutdown()
    return loop.timing(), jobs


class _Cycle:
    def __init__(self) -> None:
        self.me = self


def _allocating(settings: LoopSettings, duration: float, in_slack: bool) -> dict[str, float | int | str]:
    """The idle loop's timing while another thread makes cyclic garbage over a large heap."""
    heap = [[_Cycle() for _ in range(100)] for _ in range(5000)]
    amplifier, sensor = _InstantAmplifier(), _StillSensor()
    loop = ControlLoop(amplifier, sensor, MODES, settings, collect_in_slack=in_slack)
    loop.start()
    recent: deque[_Cycle] = deque(maxlen=2000)
    end = time.monotonic() + duration
    while time.monotonic() < end:
        for k in range(1000):
            made = _Cycle()
            if k % 100 == 0:
                recent.append(made)
        time.sleep(0.002)
    loop.shutdown()
    del heap
    return loop.timing()


STATUS = {"timing": {f"t{k}": k * 1e-3 for k in range(50)}, "history": [[k, k * 0.5] for k in range(200)]}
"""A reply the size of the daemon's status (~5 kB of JSON)."""


def _serving(settings: LoopSettings, duration: float, quiet: bool) -> dict[str, float | int | str]:
    """The idle loop's timing while other threads answer requests (see the module's docstring)."""
    loop = ControlLoop(_InstantAmplifier(), _StillSensor(), MODES, settings)
    loop.start()
    end = time.monotonic() + duration
    hold = loop.quiet.hold if quiet else lambda: None

    async def request() -> None:
        for _ in range(3):
            json.dumps(STATUS)
            await asyncio.sleep(0)

    async def clients() -> None:
        while time.monotonic() < end:
            await asyncio.gather(*(request() for _ in range(100)))

    def worker() -> None:
        while time.monotonic() < end:
            hold()
            json.dumps(STATUS)
            time.sleep(0.0005)

    events = quiet_event_loop(loop.quiet) if quiet else asyncio.new_event_loop()
    threads = [threading.Thread(target=events.run_until_complete, args=(clients(),))]
    threads += [threading.Thread(target=worker) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    events.close()
    loop.shutdown()
    return loop.timing()


def _prefixed(runs: dict[str, dict[str, float | int | str]], keys: tuple[str, ...]) -> dict[str, float]:
    """Each run's p99 and max lateness and ``keys``, named ``run_key``."""
    return {
        f"{name}_{key}": float(timing[key])
        for name, timing in runs.items()
        for key in ("jitter_p99_s", "jitter_max_s", *keys)
    }


def run(quick: bool) -> dict[str, float | int]:
    duration = 2.0 if quick else 10.0
    settings = LoopSettings()
    baseline = _sleep_loop(settings.rate_hz, duration)
    loop = ControlLoop(_InstantAmplifier(), _StillSensor(), MODES, settings)
    loop.start()
    time.sleep(duration)
    loop.shutdown()
    timing = loop.timing()
    slow, jobs = _busy_with_slow_commits(settings, duration)
    base_p99 = float(np.percentile(baseline, 99))
    collector = _allocating(settings, duration, in_slack=True)
    automatic = _allocating(settings, duration, in_slack=False)
    requests = _serving(settings, duration, quiet=True)
    unheld = _serving(settings, duration, quiet=False)
    return {
        "ratio": base_p99 / max(float(timing["jitter_p99_s"]), 1e-9),
        "rate_hz": settings.rate_hz,
        "duration_s": duration,
        "ticks": int(timing["ticks"]),
        "overruns": int(timing["overruns"]),
        "jitter_p50_s": float(timing["jitter_p50_s"]),
        "jitter_p99_s": float(timing["jitter_p99_s"]),
        "jitter_max_s": float(timing["jitter_max_s"]),
        "baseline_p50_s": float(np.percentile(baseline, 50)),
        "baseline_p99_s": base_p99,
        "baseline_max_s": float(baseline.max()),
        "slow_commit_s": SLOW_COMMIT_S,
        "slow_commit_moves": jobs,
        "slow_commit_overruns": int(slow["overruns"]),
        "slow_commit_jitter_p99_s": float(slow["jitter_p99_s"]),
        "slow_commit_jitter_max_s": float(slow["jitter_max_s"]),
        "collector_ratio": float(automatic["jitter_max_s"]) / max(float(collector["jitter_max_s"]), 1e-9),
        **_prefixed({"collector": collector, "automatic": automatic}, ("overruns", "collection_max_s")),
        "requests_ratio": float(unheld["jitter_p99_s"]) / max(float(requests["jitter_p99_s"]), 1e-9),
        **_prefixed({"requests": requests, "unheld": unheld}, ("jitter_p50_s", "quiet_holds")),
    }
