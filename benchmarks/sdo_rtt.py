"""Expedited SDO read over slcan-pty: ``canopen`` master → firmware_sim's CANopen node.

The host is a plain ``canopen`` master on python-can's ``slcan`` interface,
reading ``Step counter`` (0x2012) of node 1 of ``python -m firmware_sim --can
slcan-pty``: request line → pty → emulated adapter → CAN wire → node (SDO
server, firmware lock) → back the same way, all in the adapter's pty thread.

Floor: the same master against a bare SLCAN responder process that answers
every SDO request line at once with a canned expedited upload response (and
``z`` like a real adapter): the cost of the pty, python-can's slcan parsing and
the canopen client, without adapter emulation, bus or node.  2000 reads each
(200 with ``--quick``), in alternating batches of 20 so that both see the same
load on a shared machine; figures: median and p99 per read, and the median's
excess over the floor (the acceptance figure, at most 100 µs).
ratio = floor median / firmware_sim median (1.0: the node and adapter cost nothing).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

import canopen
import numpy as np
from pty_floor import FLAG, floor_pty, serve

from feeder.daemon.launcher import Simulator
from feeder.protocol.eds import object_dictionary

NODE_ID = 1
SLCAN = {"interface": "slcan", "bitrate": 500000, "sleep_after_open": 0}
BATCH = 20


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
        node = network.add_node(NODE_ID, object_dictionary(NODE_ID))
        node.sdo.RESPONSE_TIMEOUT = 2.0
        yield network, node
    finally:
        network.disconnect()


def _read_times(node: canopen.RemoteNode, count: int) -> list[float]:
    """Wall time of ``count`` expedited reads of ``Step counter``, seconds each."""
    index = node.object_dictionary["Step counter"].index
    times = []
    for _ in range(count):
        start = time.perf_counter()
        node.sdo.upload(index, 0)
        times.append(time.perf_counter() - start)
    return times


def run(quick: bool) -> dict[str, object]:
    count = 200 if quick else 2000
    floor: list[float] = []
    ours: list[float] = []
    with (
        floor_pty(__file__) as floor_path,
        firmware_sim_pty() as our_path,
        master(floor_path) as (_, floor_node),
        master(our_path) as (_, our_node),
    ):
        _read_times(floor_node, 20)  # warm up (first frames, caches)
        _read_times(our_node, 20)
        for _ in range(count // BATCH):  # interleaved: both see the same machine load
            floor += _read_times(floor_node, BATCH)
            ours += _read_times(our_node, BATCH)
    return {
        "ratio": float(np.median(floor) / np.median(ours)),
        "reads": count,
        "median_us": 1e6 * float(np.median(ours)),
        "p99_us": 1e6 * float(np.percentile(ours, 99)),
        "floor_median_us": 1e6 * float(np.median(floor)),
        "floor_p99_us": 1e6 * float(np.percentile(floor, 99)),
        "median_minus_floor_us": 1e6 * float(np.median(ours) - np.median(floor)),
    }


if __name__ == "__main__":
    if FLAG in sys.argv:
        serve(b"\r", _floor_reply)
    else:
        print(run(quick="--quick" in sys.argv))
