"""A part's pose on the plate and its distance from a target pose.

A pose is (x_m, y_m, psi_rad): the part's centre in the plate frame (origin at
the rotation centre O) and the direction of its first dimension from +x
towards +y.  Angles compare modulo the part's symmetry (π for a rectangle,
π/2 for a square, 0 for a disc: any angle is the same).
"""

from __future__ import annotations

import math

from feeder.errors import InputError
from feeder.vision.model import angle_difference

Pose = tuple[float, float, float]


def pose_error(pose: Pose, target: Pose, symmetry_rad: float) -> tuple[float, float]:
    """(distance of the centres in m, |angle difference| in rad modulo ``symmetry_rad``)."""
    distance = math.hypot(pose[0] - target[0], pose[1] - target[1])
    if symmetry_rad <= 0:
        return distance, 0.0
    return distance, abs(angle_difference(pose[2], target[2], symmetry_rad))


def parse_poses(text: str, option: str) -> tuple[Pose, ...]:
    """``X,Y,PSI;X,Y,PSI;...`` (m, m, rad, plate frame) → poses; :class:`InputError` names ``option``."""
    poses = []
    for item in text.split(";"):
        fields = item.split(",")
        try:
            values = [float(f) for f in fields]
        except ValueError:
            values = []
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise InputError(option, f"expected X,Y,PSI (m, m, rad) per part, separated by ';', got {item!r}")
        poses.append((values[0], values[1], values[2]))
    return tuple(poses)
