"""Expedited SDO read over slcan-pty: ``canopen`` master → firmware_sim's CANopen node.

The host is a plain ``canopen`` master on python-can's ``slcan`` interface,
reading object 0x2012 (step counter) of node 1 of ``python -m firmware_sim --can
slcan-pty``: request line → pty → emulated adapter → virtual bus → node (SDO
server, firmware lock) → back the same way.

Floor: the same master against a bare SLCAN responder process that answers
every SDO request line at once with a canned expedited upload response (and
``z`` like a real adapter): the cost of the pty, python-can's slcan parsing and
the canopen client, without adapter emulation, bus or node.  2000 reads each
(200 with ``--quick``); figures: median and p99 per read.
ratio = floor median / firmware_sim median (1.0: the node and adapter cost nothing).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import canopen
import numpy as np
from pty_floor import FLAG, floor_pty, serve

from feeder.daemon.launcher import Simulator

EDS = Path(__file__).resolve().parents[1] / "firmware_sim" / "feeder_amplifier.eds"
NODE_ID = 1
SLCAN = {"interface": "slcan", "bitrate": 500000, "sleep_after_open": 0}


def _floor_reply(line: bytes) -> bytes:
    """A bare SLCAN adapter with node 1 behind it, in one function."""
    if line.startswith(b"t%03X8" % (0x600 + NODE_ID)):
        index_sub = line[7:13]
        return b"z\r" + b"t%03X843%s00000000\r" % (0x580 + NODE_ID, index_sub)
    if line.startswith(b"t080"):  # SYNC → TPDO1 (for pdo_rate)
        return b"z\rt%03X80000000000000000\r" % (0x180 + NODE_ID)
    if line.startswith(b"t"):
        return b"z\r"
    return b"V1013\r" if line == b"V" else b"\r"


@contextmanager
def firmware_sim_pty() -> Iterator[str]:
    """``python -m firmware_sim --can slcan-pty``; yields the slcan pty path."""
    simulator = Simulator(["--can", "slcan-pty"])
    try:
        yield simulator.endpoints["slcan_pty"]
    finally:
        simulator.stop()


@contextmanager
def master(path: str) -> Iterator[tuple[canopen.Network, canopen.RemoteNode]]:
    """A plain canopen master for node 1 on the slcan pty at ``path``."""
    network = canopen.Network()
    network.connect(channel=path, **SLCAN)
    try:
        node = network.add_node(NODE_ID, str(EDS))
        node.sdo.RESPONSE_TIMEOUT = 2.0
        yield network, node
    finally:
        network.disconnect()


def _reads(path: str, count: int) -> np.ndarray:
    with master(path) as (_, node):
        for _ in range(20):  # warm up (first frames, caches)
            node.sdo.upload(0x2012, 0)
        times = np.empty(count)
        for i in range(count):
            start = time.perf_counter()
            node.sdo.upload(0x2012, 0)
            times[i] = time.perf_counter() - start
        return times


def run(quick: bool) -> dict[str, object]:
    count = 200 if quick else 2000
    with floor_pty(__file__) as path:
        floor = _reads(path, count)
    with firmware_sim_pty() as path:
        ours = _reads(path, count)
    return {
        "ratio": float(np.median(floor) / np.median(ours)),
        "reads": count,
        "median_us": 1e6 * float(np.median(ours)),
        "p99_us": 1e6 * float(np.percentile(ours, 99)),
        "floor_median_us": 1e6 * float(np.median(floor)),
        "floor_p99_us": 1e6 * float(np.percentile(floor, 99)),
    }


if __name__ == "__main__":
    if FLAG in sys.argv:
        serve(b"\r", _floor_reply)
    else:
        print(run(quick="--quick" in sys.argv))
