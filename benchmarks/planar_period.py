"""Planar stick-slip per period vs the fine-step reference (regularised Coulomb, Radau), same run.

A 300×200×50 part 2 mm from O under a θ sawtooth (7 mrad, 100 Hz, 0.35 ms
linear flyback, F_k/F_s 0.8): ``ratio`` = reference time per period / ours.
The reference is the one in tests/test_planar.py (a 20×20 Gauss grid of the
patch, ε = 2e-5 m/s); ``relative_difference`` is how far the two pose changes
differ in the second period.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from timing import best_time

from feeder.parts import Part
from feeder.plant.planar import PlanarPart, simulate
from feeder.plant.plate_motion import sawtooth
from feeder.plant.stick_slip import Friction

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_planar import reference_changes

POSE, STROKE = (2e-3, 0.0, 0.0), (0.0, 0.0, 7e-3)


def run(quick: bool) -> dict:
    periods = 2 if quick else 6
    part = PlanarPart.from_part(Part.parse("300x200x50"), Friction(105.25, 0.8), POSE)
    motion = sawtooth(STROKE, 100.0, 3.5e-4, "linear", periods)
    ours = simulate([part], motion).changes[0]
    t_ours = best_time(lambda: simulate([part], motion), repeats=3) / periods
    ref = reference_changes(part, STROKE, "linear", periods=2)
    t_ref = best_time(lambda: reference_changes(part, STROKE, "linear", periods=1), repeats=1)
    difference = float(np.linalg.norm(ours[1, :2] - ref[1, :2]) / np.linalg.norm(ref[1, :2]))
    return {
        "ratio": t_ref / t_ours,
        "periods_per_s": 1 / t_ours,
        "reference_periods_per_s": 1 / t_ref,
        "relative_difference": difference,
        "turn_relative_difference": float(abs(ours[1, 2] / ref[1, 2] - 1)),
    }
