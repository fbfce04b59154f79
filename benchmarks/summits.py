"""Summit statistics of a 4096×4096 height map vs a straightforward maximum_filter baseline.

Ours: :func:`feeder.surface.statistics.surface_statistics` (plane removal, blocked
8-neighbour summit search, Sq, μ, η, R). Baseline: the same analysis with the summits
found the straightforward way, ``h > scipy.ndimage.maximum_filter(h, footprint=ring)``
(3×3 ring without the centre), and Sq as ``sqrt(mean(h**2))``. Both give the same summits.
Target: the whole analysis of a 4096² map under 1 s.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from timing import best_time

from feeder.surface.reading import HeightMap
from feeder.surface.statistics import find_summits, remove_plane, summit_curvatures, surface_statistics


def _baseline(height_map: HeightMap) -> tuple[int, float, float]:
    heights = remove_plane(height_map.heights_m)
    sq = math.sqrt(float(np.mean(heights**2)))
    ring = np.ones((3, 3), bool)
    ring[1, 1] = False
    neighbours = ndimage.maximum_filter(heights, footprint=ring, mode="constant", cval=np.inf)
    rows, cols = np.nonzero(heights > neighbours)
    curvature = summit_curvatures(heights, rows, cols, height_map.pixel_size_m)
    return int(rows.size), sq, float(np.mean(-1.0 / curvature[curvature < 0]))


def run(quick: bool) -> dict[str, float | int]:
    n = 1024 if quick else 4096
    rng = np.random.default_rng(0)
    rough = ndimage.gaussian_filter(rng.normal(size=(n, n)), 3.0)
    i = np.arange(n)[:, None]
    heights = (rough / rough.std() + 1e-3 * i) * 1e-9  # 1 nm rough surface on a small tilt
    height_map = HeightMap(heights, (2e-9, 2e-9), "synthetic")
    stats = surface_statistics(height_map)
    count, sq, radius = _baseline(height_map)
    if count != stats.summit_count or not math.isclose(sq, stats.sq_m, rel_tol=1e-9):
        raise AssertionError("baseline and ours disagree")
    if not math.isclose(radius, stats.mean_summit_radius_m, rel_tol=1e-9):
        raise AssertionError("baseline and ours disagree on the radius")
    ours = best_time(lambda: surface_statistics(height_map))
    baseline = best_time(lambda: _baseline(height_map))
    detrended = remove_plane(heights)
    ring = np.ones((3, 3), bool)
    ring[1, 1] = False
    ours_summits = best_time(lambda: find_summits(detrended))
    filter_summits = best_time(
        lambda: np.nonzero(
            detrended > ndimage.maximum_filter(detrended, footprint=ring, mode="constant", cval=np.inf)
        )
    )
    return {
        "ratio": baseline / ours,
        "map_size": n,
        "summits": stats.summit_count,
        "ours_s": ours,
        "baseline_s": baseline,
        "summit_search_ratio": filter_summits / ours_summits,
        "ours_summit_search_s": ours_summits,
        "maximum_filter_search_s": filter_summits,
    }
