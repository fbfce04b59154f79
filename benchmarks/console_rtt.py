"""Console round trip: ``getf 1`` over the pty to firmware_sim vs an echo-only pty responder.

Both ends are separate processes on a pty, read with pyserial the way the host
driver reads: write the command, read up to ``OK``.  The floor is a process
that answers every line with a canned ``frequency = 100 Hz`` / ``OK`` at once
(pty + scheduler + pyserial cost, no console).  2000 round trips each (200 with
``--quick``), in 10 interleaved rounds; figures: median and p99 per round trip.
ratio = floor median / firmware_sim median (1.0: the console costs nothing).
"""

from __future__ import annotations

import sys
import time

import numpy as np
import serial
from pty_floor import FLAG, floor_pty, serve

from feeder.daemon.launcher import Simulator

REPLY = b"frequency = 100 Hz\r\nOK\r\n"
ROUNDS = 10


def _open(path: str) -> serial.SerialBase:
    port = serial.serial_for_url(path, timeout=2.0)
    time.sleep(0.05)
    port.reset_input_buffer()
    port.write(b"echo off\r\n")
    port.read_until(b"OK\r\n")
    return port


def _round_trips(port: serial.SerialBase, count: int) -> np.ndarray:
    times = np.empty(count)
    for i in range(count):
        start = time.perf_counter()
        port.write(b"getf 1\r\n")
        reply = port.read_until(b"OK\r\n")
        times[i] = time.perf_counter() - start
        if not reply.endswith(b"OK\r\n"):
            raise RuntimeError(f"{port.port}: no reply to getf")
    return times


def run(quick: bool) -> dict[str, object]:
    count = 200 if quick else 2000
    simulator = Simulator(["--console", "pty"])
    floor: list[np.ndarray] = []
    ours: list[np.ndarray] = []
    try:
        with floor_pty(__file__) as floor_path:
            floor_port = _open(floor_path)
            our_port = _open(simulator.endpoints["console_pty"])
            for _ in range(ROUNDS):  # interleaved, so both see the same machine load
                floor.append(_round_trips(floor_port, count // ROUNDS))
                ours.append(_round_trips(our_port, count // ROUNDS))
            floor_port.close()
            our_port.close()
    finally:
        simulator.stop()
    floor_times, our_times = np.concatenate(floor), np.concatenate(ours)
    return {
        "ratio": float(np.median(floor_times) / np.median(our_times)),
        "round_trips": int(our_times.size),
        "median_us": 1e6 * float(np.median(our_times)),
        "p99_us": 1e6 * float(np.percentile(our_times, 99)),
        "floor_median_us": 1e6 * float(np.median(floor_times)),
        "floor_p99_us": 1e6 * float(np.percentile(floor_times, 99)),
    }


if __name__ == "__main__" and FLAG in sys.argv:
    serve(b"\n", lambda line: REPLY)
