"""TPDO frames per second delivered without loss, over slcan-pty from firmware_sim's node.

A plain ``canopen`` master sets node 1's TPDO1 to transmission type 1 (one TPDO
per SYNC), starts the node and sends SYNCs paced at a rising rate (0.5 s per
rate, 0.2 s with ``--quick``; every millisecond the SYNCs due by then, sleeping
in between so the host's receive thread is never starved by the pacing); at
each rate it counts the TPDOs that arrive within 0.5 s after the last SYNC.
The figure is the highest rate at which every SYNC got its TPDO.

Floor: the same ladder against the bare SLCAN responder of :mod:`sdo_rtt`, which
answers each SYNC line with a TPDO line at once (pty + python-can + canopen on
the host, no adapter emulation, bus or node).
ratio = our lossless rate / the floor's (time per frame of the floor / ours).
"""

from __future__ import annotations

import sys
import threading
import time

import sdo_rtt
from pty_floor import floor_pty
from sdo_rtt import NODE_ID, firmware_sim_pty, master

RATES_HZ = (250, 500, 1000, 2000, 3000, 4000, 6000, 8000, 12000, 16000)
GRACE_S = 0.5
PACE_S = 0.001


def _delivered(
    path: str, rates: tuple[int, ...], seconds: float, node_present: bool
) -> tuple[int, dict[int, int]]:
    """Highest lossless rate and the TPDOs lost at each rate tried."""
    with master(path) as (network, node):
        if node_present:
            node.sdo["TPDO1 communication parameter"]["Transmission type"].raw = 1
            node.nmt.state = "OPERATIONAL"
        received = 0
        lock = threading.Lock()

        def count(can_id: int, data: bytearray, timestamp: float) -> None:
            nonlocal received
            with lock:
                received += 1

        network.subscribe(0x180 + NODE_ID, count)
        best, lost = 0, {}
        for rate in rates:
            time.sleep(0.2)
            with lock:
                received = 0
            syncs = round(rate * seconds)
            start = time.perf_counter()
            sent = 0
            while sent < syncs:
                due = min(syncs, int((time.perf_counter() - start) * rate) + 1)
                for _ in range(due - sent):
                    network.send_message(0x80, b"")
                sent = due
                time.sleep(PACE_S)
            time.sleep(GRACE_S)
            with lock:
                lost[rate] = syncs - received
            if lost[rate]:
                break
            best = rate
        return best, lost


def run(quick: bool) -> dict[str, object]:
    seconds = 0.2 if quick else 0.5
    rates = RATES_HZ[:4] if quick else RATES_HZ
    with floor_pty(sdo_rtt.__file__) as path:
        floor_rate, _ = _delivered(path, rates, seconds, node_present=False)
    with firmware_sim_pty() as path:
        our_rate, our_lost = _delivered(path, rates, seconds, node_present=True)
    return {
        "ratio": our_rate / floor_rate if floor_rate else float("nan"),
        "lossless_tpdo_per_s": our_rate,
        "floor_lossless_tpdo_per_s": floor_rate,
        "lost_at_first_failing_rate": {str(k): v for k, v in our_lost.items() if v},
        "rates_tried_hz": list(our_lost),
    }


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
