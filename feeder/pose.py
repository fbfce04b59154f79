"""A part's pose on the plate and its distance from a target pose.

A pose is (x_m, y_m, psi_rad): the part's centre in the plate frame (origin at
the rotation centre O) and the direction of its first dimension from +x
towards +y.  Angles compare modulo the part's symmetry (π for a rectangle,
π/2 for a square, 0 for a disc: any angle is the same).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

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


MAX_POSE_M = 0.1
"""A part's pose on the plate: |x|, |y| at most this, m (a plate is a few cm across; a stack
strokes ~14 µm at 200 V).  Checked once, by :func:`part_pose`, for every pose a user gives:
``[plate] parts``, ``firmware_sim --parts``, ``feeder simulate --pose``, ``feeder waveform design
--pose``/``--radius-m``."""

MAX_PSI_RAD = 2 * math.pi
"""A part's pose on the plate: |ψ| at most one turn, rad (beyond, a typo: degrees given as rad)."""


def part_pose(values: Sequence[float], field: str, shown: str | None = None) -> Pose:
    """``values`` as a part's pose on the plate (x_m, y_m, ψ_rad): three finite numbers with
    |x|, |y| ≤ :data:`MAX_POSE_M` and |ψ| ≤ :data:`MAX_PSI_RAD`; else :class:`InputError`
    naming ``field`` (``shown``: the input as given, quoted in the message; default the values)."""
    text = ",".join(f"{v:g}" for v in values) if shown is None else shown
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise InputError(field, f"expected three finite numbers X,Y,PSI (m, m, rad), got {text}")
    x, y, psi = (float(v) for v in values)
    if not (abs(x) <= MAX_POSE_M and abs(y) <= MAX_POSE_M and abs(psi) <= MAX_PSI_RAD):
        raise InputError(
            field, f"needs |X|, |Y| ≤ {MAX_POSE_M:g} m and |PSI| ≤ 2π rad (a part on the plate), got {text}"
        )
    return x, y, psi


def part_poses(text: str, field: str) -> tuple[Pose, ...]:
    """``X,Y,PSI;X,Y,PSI;...`` (m, m, rad; :func:`parse_poses`), each a
    :func:`part_pose`; :class:`InputError` naming ``field`` (and the part, of several)."""
    poses = parse_poses(text, field)
    for k, pose in enumerate(poses, 1):
        try:
            part_pose(pose, field)
        except InputError as err:
            raise InputError(field, f"part {k}: {err.message}" if len(poses) > 1 else err.message) from None
    return poses
