"""Console round trip: ``getf 1`` over the pty to firmware_sim vs an echo-only pty responder.

Both ends are separate processes on a pty, read with pyserial the way the host
driver reads: write the command, read up to ``OK``.  The floor is a process
that answers every line with a canned ``frequency = 100 Hz`` / ``OK`` at once
(pty + scheduler + pyserial cost, no console).  2000 round trips each (200 with
``--quick``); figures: median and p99 per round trip.
ratio = floor median / firmware_sim median (1.0: the console costs nothing).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
import tty

import numpy as np
import serial

from feeder.daemon.launcher import Simulator

REPLY = b"frequency = 100 Hz\r\nOK\r\n"


def _round_trips(path: str, count: int) -> np.ndarray:
    port = serial.serial_for_url(path, timeout=2.0)
    try:
        time.sleep(0.05)
        port.reset_input_buffer()
        port.write(b"echo off\r\n")
        port.read_until(b"OK\r\n")
        times = np.empty(count)
        for i in range(count):
            start = time.perf_counter()
            port.write(b"getf 1\r\n")
            reply = port.read_until(b"OK\r\n")
            times[i] = time.perf_counter() - start
            if not reply.endswith(b"OK\r\n"):
                raise RuntimeError(f"{path}: no reply to getf")
        return times
    finally:
        port.close()


def _echo_responder() -> None:
    """Serve canned replies on a new pty; prints its path, runs until killed."""
    master, slave = os.openpty()
    tty.setraw(slave)
    print(os.ttyname(slave), flush=True)
    pending = b""
    while True:
        pending += os.read(master, 4096)
        *lines, pending = pending.split(b"\n")
        if lines:
            os.write(master, REPLY * len(lines))


def run(quick: bool) -> dict[str, object]:
    count = 200 if quick else 2000
    floor = subprocess.Popen([sys.executable, __file__, "--echo-responder"],
                             stdout=subprocess.PIPE, text=True)
    try:
        assert floor.stdout is not None
        floor_times = _round_trips(floor.stdout.readline().strip(), count)
    finally:
        floor.kill()
        floor.wait()
    simulator = Simulator(["--console", "pty"])
    try:
        ours = _round_trips(simulator.endpoints["console_pty"], count)
    finally:
        simulator.stop()
    return {
        "ratio": float(np.median(floor_times) / np.median(ours)),
        "round_trips": count,
        "median_us": 1e6 * float(np.median(ours)),
        "p99_us": 1e6 * float(np.percentile(ours, 99)),
        "floor_median_us": 1e6 * float(np.median(floor_times)),
        "floor_p99_us": 1e6 * float(np.percentile(floor_times, 99)),
    }


if __name__ == "__main__" and "--echo-responder" in sys.argv:
    _echo_responder()
