"""Firmware tick jitter: the real-time 1 kHz tick vs a bare ``time.sleep`` deadline loop.

Both run for 10 s (2 s with ``--quick``) on monotonic deadlines, one after the
other in this process.  The firmware ticks with the world attached (the plant
simulated on every played sample) and axis 1 stepping continuously at 100 Hz,
200 V, so each tick does its real work.  Figures: p50/p99/max jitter (wake −
deadline), late ticks (> one period), DAC underruns (the goal is 0).
ratio = baseline p99 jitter / firmware p99 jitter (1.0: the tick's work adds
nothing to what the OS scheduler gives).
"""

from __future__ import annotations

import threading
import time

import numpy as np

from firmware_sim.clock import RealTimeClock
from firmware_sim.firmware import Firmware, FirmwareConfig
from firmware_sim.world import World, WorldConfig

TICK_HZ = 1000.0


def _bare_loop_jitter(seconds: float) -> np.ndarray:
    period = 1.0 / TICK_HZ
    start = time.monotonic()
    jitter = []
    for k in range(int(seconds * TICK_HZ)):
        deadline = start + k * period
        remaining = deadline - time.monotonic()
        if remaining > 0:
            time.sleep(remaining)
        jitter.append(time.monotonic() - deadline)
    return np.asarray(jitter)


def run(quick: bool) -> dict[str, object]:
    seconds = 2.0 if quick else 10.0
    baseline = _bare_loop_jitter(seconds)

    config = FirmwareConfig(tick_hz=TICK_HZ)
    firmware = Firmware(config)
    World(WorldConfig(), config).attach(firmware)
    axis = firmware.axis(1)
    axis.set_amplitude(config.amplifier.max_amplitude_vpp)
    axis.set_mode("stp")
    axis.run_continuous(up=True)
    stop = threading.Event()
    timer = threading.Timer(seconds, stop.set)
    timer.start()
    firmware.run(RealTimeClock(), stop)
    summary = firmware.tick_summary()
    base_p99 = float(np.percentile(baseline, 99))
    return {
        "ratio": base_p99 / max(float(summary["jitter_p99_s"]), 1e-9),
        "seconds": seconds,
        "ticks": summary["ticks"],
        "jitter_p50_us": 1e6 * float(summary["jitter_p50_s"]),
        "jitter_p99_us": 1e6 * float(summary["jitter_p99_s"]),
        "jitter_max_us": 1e6 * float(summary["jitter_max_s"]),
        "late_ticks": summary["late_ticks"],
        "missed_deadlines": summary["missed_deadlines"],
        "underruns": summary["underruns"],
        "world_wait_ms": 1e3 * float(summary["world_wait_s"]),
        "steps": axis.status().step_counter,
        "baseline_p50_us": 1e6 * float(np.percentile(baseline, 50)),
        "baseline_p99_us": 1e6 * base_p99,
        "baseline_max_us": 1e6 * float(baseline.max()),
    }
