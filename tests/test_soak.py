"""Soak (``--runslow``): the daemon on the embedded simulator runs many random moves both ways.

Every move must end ``done`` within tolerance, the history must hold each of
them, and the state database must pass SQLite's integrity check afterwards.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
from test_daemon_hil import DaemonProcess, assert_within_tolerance, base  # noqa: F401  (fixture)

MOVES = 60

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]


def test_many_random_moves_all_converge(base: Path) -> None:  # noqa: F811
    daemon = DaemonProcess(base)
    try:
        low, high = daemon.request("status")["travel_limits_m"]
        span = 0.4 * min(high, -low)
        targets = np.random.default_rng(11).uniform(-span, span, MOVES)
        results = [daemon.request("move", target_m=float(t)) for t in targets]
        status = daemon.request("status")
        history = daemon.request("history", limit=MOVES)["moves"]
    finally:
        assert daemon.stop() == 0
    assert_within_tolerance(results, status["tolerance_m"])
    assert len(history) == MOVES
    assert all(move["status"] == "done" for move in history)
    databases = list((base / "state").glob("*.sqlite*")) + list((base / "state").glob("*.db"))
    main = next(p for p in databases if p.suffix in (".sqlite", ".db"))
    with sqlite3.connect(main) as db:
        assert db.execute("PRAGMA integrity_check").fetchone() == ("ok",)
