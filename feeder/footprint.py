"""The gap between two parts' footprints on the plate (m): rectangles L×W turned by ψ, discs of diameter L.

Exact, not bounding circles: two 300 µm squares side by side 360 µm apart
(centre to centre) are 60 µm apart, though their circumscribed circles
overlap.  Two rectangles overlap unless one of the four axes of their sides
separates them (separating axes); apart, the nearest points of two convex
polygons include a corner of one of them, so the gap is the smallest distance
from a corner of either to the other.  A pose whose angle is NaN ("any
angle", a target that leaves it free) stands for the disc the part sweeps as
it turns: its circumscribed circle.
"""

from __future__ import annotations

import math

from feeder.plant.limit_surface import Patch
from feeder.pose import Pose


def gap_m(patch: Patch, a: Pose, b: Pose) -> float:
    """Distance (m) between the footprints of two parts of ``patch`` at poses ``a`` and ``b``
    (m, m, rad; plate frame); 0 when they touch or overlap."""
    round_a, round_b = _round_radius(patch, a), _round_radius(patch, b)
    if round_a is not None and round_b is not None:
        return max(math.hypot(b[0] - a[0], b[1] - a[1]) - round_a - round_b, 0.0)
    if round_a is not None:
        return max(_point_gap(patch, b, a[0], a[1]) - round_a, 0.0)
    if round_b is not None:
        return max(_point_gap(patch, a, b[0], b[1]) - round_b, 0.0)
    if _overlap(patch, a, b):
        return 0.0
    return min(
        min(_point_gap(patch, b, x, y) for x, y in _corners(patch, a)),
        min(_point_gap(patch, a, x, y) for x, y in _corners(patch, b)),
    )


def _round_radius(patch: Patch, pose: Pose) -> float | None:
    """The radius (m) of a round footprint (a disc; any part at a NaN angle), None for a rectangle."""
    if patch.shape == "disc" or math.isnan(pose[2]):
        return patch.radius_m
    return None


def _point_gap(patch: Patch, pose: Pose, x: float, y: float) -> float:
    """Distance (m) from the point (x, y) to the rectangle of ``patch`` at ``pose`` (0 inside)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = x - pose[0], y - pose[1]
    u, v = c * dx + s * dy, -s * dx + c * dy  # in the part's frame
    return math.hypot(max(abs(u) - 0.5 * patch.length_m, 0.0), max(abs(v) - 0.5 * patch.width_m, 0.0))


def _corners(patch: Patch, pose: Pose) -> list[tuple[float, float]]:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    hl, hw = 0.5 * patch.length_m, 0.5 * patch.width_m
    return [
        (pose[0] + i * hl * c - j * hw * s, pose[1] + i * hl * s + j * hw * c)
        for i, j in ((1, 1), (1, -1), (-1, -1), (-1, 1))
    ]


def _overlap(patch: Patch, a: Pose, b: Pose) -> bool:
    """True unless an axis of either rectangle's sides separates them (touching: apart)."""
    hl, hw = 0.5 * patch.length_m, 0.5 * patch.width_m
    dx, dy = b[0] - a[0], b[1] - a[1]
    ca, sa, cb, sb = math.cos(a[2]), math.sin(a[2]), math.cos(b[2]), math.sin(b[2])
    sides = ((ca, sa), (-sa, ca), (cb, sb), (-sb, cb))  # each rectangle's length, then width axis
    for k, (ex, ey) in enumerate(sides):
        # half-extents along the axis: the own rectangle's side, the other's two sides projected
        (lx, ly), (wx, wy) = sides[2:] if k < 2 else sides[:2]
        own = hl if k % 2 == 0 else hw
        projected = hl * abs(ex * lx + ey * ly) + hw * abs(ex * wx + ey * wy)
        if abs(ex * dx + ey * dy) >= own + projected:
            return False
    return True
