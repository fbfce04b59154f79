"""Compile numba's kernels once, ahead of use (``make`` runs it after installing).

numba compiles a kernel on its first call and caches the machine code beside
the source; the planar solver's kernels take tens of seconds to compile.
Running every compiled path here once (a 1-D plant chunk, one period of the
planar plant under an x and a θ drive, a streaming planar chunk) means the
first simulation, the daemon's planner seed and firmware_sim's plant start at
full speed.  Without numba (no extra ``fast``) there is nothing to do.

Usage: ``python -m feeder.plant.warm_kernels``
"""

from __future__ import annotations

import logging
import sys
import time

import numpy as np

from feeder.parts import Part
from feeder.plant import kernels
from feeder.plant.planar import PlanarPart, simulate
from feeder.plant.planar_plant import PlanarPlant
from feeder.plant.plant import Plant
from feeder.plant.plate_motion import sawtooth
from feeder.plant.stick_slip import Friction

log = logging.getLogger(__name__)


def warm() -> float:
    """Run every compiled path once; the seconds it took (0 without numba)."""
    if not kernels.enabled():
        return 0.0
    started = time.perf_counter()
    friction = Friction(105.0, 0.8)
    Plant(friction).advance(np.linspace(0.0, 40.0, 100))
    part = PlanarPart.from_part(Part.parse("300x300x50"), friction, (1e-3, 0.0, 0.2))
    for stroke in ((3e-6, 0.0, 0.0), (0.0, 0.0, 5e-3)):
        simulate([part], sawtooth(stroke, 1000.0, 1e-4, "linear", 2))
    t = np.arange(200) / 100_000.0
    PlanarPlant([part]).advance(np.vstack([40.0 * ((t * 1000.0) % 1.0)] * 3))
    return time.perf_counter() - started


def main() -> int:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    seconds = warm()
    if seconds:
        log.info("numba kernels compiled and cached in %.1f s", seconds)
    else:
        log.info("numba not in use: nothing to compile")
    return 0


if __name__ == "__main__":
    sys.exit(main())
