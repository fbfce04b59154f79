"""A rigid part on the plate for the planar plant (:mod:`.planar`): its patch, mass, inertia,
friction and pose (x, y, ψ in the plate frame: m, m, rad), and the overlap check of several."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feeder.errors import InputError
from feeder.parts import Part
from feeder.plant.limit_surface import Patch
from feeder.plant.stick_slip import Friction

Pose = tuple[float, float, float]


@dataclass(frozen=True)
class PlanarPart:
    """A rigid part on the plate: patch, mass (kg), inertia about its centre (kg·m²), friction, pose."""

    patch: Patch
    mass_kg: float
    inertia_kg_m2: float
    friction: Friction
    pose: Pose = (0.0, 0.0, 0.0)

    @classmethod
    def from_part(cls, part: Part, friction: Friction, pose: Pose = (0.0, 0.0, 0.0),
                  shape: str = "rectangle") -> PlanarPart:  # fmt: skip
        """Rectangle L×W, or a disc of diameter L (needs L = W), thickness T, the part's density."""
        if shape == "disc":
            if part.length_m != part.width_m:
                raise InputError("--part", f"a disc needs L = W (its diameter), got {part.label}")
            patch = Patch("disc", part.length_m, part.length_m)
            mass = part.density_kg_m3 * patch.area_m2 * part.thickness_m
            return cls(patch, mass, mass * part.length_m**2 / 8, friction, pose)
        patch = Patch("rectangle", part.length_m, part.width_m)
        inertia = part.mass_kg * (part.length_m**2 + part.width_m**2) / 12
        return cls(patch, part.mass_kg, inertia, friction, pose)

    @property
    def static_stress_pa(self) -> float:
        """τ_s = m·a_s/A: the friction stress over the patch at breakaway."""
        return self.mass_kg * self.friction.static_accel_m_s2 / self.patch.area_m2


def _outline(part: PlanarPart) -> tuple[np.ndarray, np.ndarray]:
    """(corner points (4, 2), unit axes (2, 2)) of a rectangle part in the plate frame."""
    x, y, psi = part.pose
    axes = np.array([[math.cos(psi), math.sin(psi)], [-math.sin(psi), math.cos(psi)]])
    half = np.array([0.5 * part.patch.length_m, 0.5 * part.patch.width_m])
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]])
    return np.array([x, y]) + (signs * half) @ axes, axes


def _overlap(a: PlanarPart, b: PlanarPart) -> bool:
    """True if the two footprints share interior points (touching is allowed)."""
    ca, cb = np.array(a.pose[:2]), np.array(b.pose[:2])
    if a.patch.shape == "disc" and b.patch.shape == "disc":
        return bool(np.linalg.norm(ca - cb) < 0.5 * (a.patch.length_m + b.patch.length_m))
    if a.patch.shape == "disc":
        a, b = b, a
    corners_a, axes_a = _outline(a)
    if b.patch.shape == "disc":  # nearest point of the rectangle to the disc's centre
        local = axes_a @ (np.array(b.pose[:2]) - np.array(a.pose[:2]))
        half = np.array([0.5 * a.patch.length_m, 0.5 * a.patch.width_m])
        return bool(np.linalg.norm(local - np.clip(local, -half, half)) < 0.5 * b.patch.length_m)
    corners_b, axes_b = _outline(b)
    for axis in (*axes_a, *axes_b):  # separating axis theorem
        pa, pb = corners_a @ axis, corners_b @ axis
        if pa.max() <= pb.min() or pb.max() <= pa.min():
            return False
    return True


def check_overlaps(parts: list[PlanarPart]) -> None:
    """InputError naming the first two parts (by index) whose footprints overlap."""
    for i, a in enumerate(parts):
        for j in range(i + 1, len(parts)):
            if _overlap(a, parts[j]):
                raise InputError("pose", f"parts {i} and {j} overlap at poses {a.pose} and {parts[j].pose}")
