"""Camera calibration: pixel size and the camera-to-plate transform (pure functions).

Model (DESIGN §9, §10): a point p = (x, y) of the plate frame (metres, origin
at the θ rotation centre O) appears in the image at

    p_img = O_img + (1 / pixel_size) · R(rotation) · F · p,   F = diag(1, −1) if mirrored else I

(image convention of feeder.vision.model).  A part's plate angle ψ appears as
rotation + ψ (rotation − ψ when mirrored); a plate turn by θ turns the image by
θ (−θ when mirrored).  A camera looking down on a plate whose y points away
from the viewer's bottom sees it mirrored (image y points down).

The parameters come from:
- the pixel size alone from a part of known size (its measured sides, px);
- scale, rotation and mirroring from moves of the x and y axes (the plate
  moves by known metres, the part's image by measured pixels; least squares
  over any number of moves, the nearest similarity to the fitted 2×2 map);
- O in the image from turns of the θ axis (a part's centre before and after a
  known turn; least squares).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from feeder.errors import InputError


@dataclass(frozen=True)
class CameraCalibration:
    """Plate ↔ image transform (see the module doc); lengths in m and px, angles in rad."""

    pixel_size_m: float
    rotation_rad: float = 0.0
    mirrored: bool = False
    origin_x_px: float = 0.0
    origin_y_px: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pixel_size_m) and self.pixel_size_m > 0):
            raise InputError("pixel_size_m", f"must be a positive number, got {self.pixel_size_m!r}")

    def _matrix(self) -> np.ndarray:
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        flip = -1.0 if self.mirrored else 1.0
        return np.array([[c, -s * flip], [s, c * flip]]) / self.pixel_size_m

    def to_image(self, x_m: float, y_m: float) -> tuple[float, float]:
        """Plate point (m) → image point (px)."""
        u, v = self._matrix() @ np.array([x_m, y_m])
        return float(u + self.origin_x_px), float(v + self.origin_y_px)

    def to_plate(self, x_px: float, y_px: float) -> tuple[float, float]:
        """Image point (px) → plate point (m)."""
        x, y = np.linalg.solve(self._matrix(), np.array([x_px - self.origin_x_px, y_px - self.origin_y_px]))
        return float(x), float(y)

    def angle_to_image(self, psi_rad: float) -> float:
        return self.rotation_rad + (-psi_rad if self.mirrored else psi_rad)

    def angle_to_plate(self, angle_rad: float) -> float:
        turn = angle_rad - self.rotation_rad
        return -turn if self.mirrored else turn

    def to_dict(self) -> dict[str, float | bool]:
        return asdict(self)

    def updated(self, record: Mapping[str, Any], source: str = "camera calibration") -> CameraCalibration:
        """This calibration with the fields ``record`` gives (a stored ``feeder vision calibrate``
        report: an origin is only there when θ turns were measured); InputError naming the field."""
        changes: dict[str, Any] = {}
        for field in fields(self):
            value = record.get(field.name)
            if value is None:
                continue
            wrong = (
                not isinstance(value, bool)
                if field.name == "mirrored"
                else (
                    isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value)
                )
            )
            if wrong:
                raise InputError(f"{source}.{field.name}", f"not a valid value: {value!r}")
            changes[field.name] = value if field.name == "mirrored" else float(value)
        try:
            return replace(self, **changes)
        except InputError as err:
            raise InputError(f"{source}.{err.field}", err.message) from None


def pixel_size_from_part(length_px: float, width_px: float, length_m: float, width_m: float) -> float:
    """Pixel size (m/px) from a part's measured sides (px) and its true footprint (m)."""
    return (length_m + width_m) / (length_px + width_px)


@dataclass(frozen=True)
class AxesFit:
    """Scale, rotation and mirroring of the plate axes in the image, from axis moves.

    residual_px: RMS of the measured image moves about the fitted similarity.
    anisotropy: relative difference of the two axes' scales (0 for a true similarity;
        a few 1e-3 is pixel aspect or axis calibration error).
    """

    pixel_size_m: float
    rotation_rad: float
    mirrored: bool
    residual_px: float
    anisotropy: float


def axes_from_moves(plate_moves_m: np.ndarray, image_moves_px: np.ndarray) -> AxesFit:
    """Least-squares fit of image move = A · plate move (A: 2×2, px/m) over ≥ 2 non-parallel moves,
    then the nearest similarity s·R(φ)·F to A."""
    plate = np.asarray(plate_moves_m, float).reshape(-1, 2)
    image = np.asarray(image_moves_px, float).reshape(-1, 2)
    if plate.shape != image.shape or plate.shape[0] < 2:
        raise InputError("moves", "need at least two plate moves, each with its image move")
    if np.linalg.matrix_rank(plate, tol=1e-3 * float(np.max(np.abs(plate)))) < 2:
        raise InputError("moves", "the plate moves must span both axes (move x and y)")
    try:
        solution, *_ = np.linalg.lstsq(plate, image, rcond=None)
        a = solution.T  # image = a @ plate
        spread = np.linalg.svd(a, compute_uv=False)
    except np.linalg.LinAlgError as err:
        raise InputError("moves", f"the axis fit failed: {err}") from None
    if not spread[-1] > 1e-6 * spread[0]:  # also 0 and NaN
        raise InputError(
            "moves",
            "the axis fit is singular: the part did not move in the images, "
            "or moved along one line for both axes (--x-move, --y-move)",
        )
    mirrored = bool(np.linalg.det(a) < 0)
    b = a @ np.diag([1.0, -1.0]) if mirrored else a
    rotation = math.atan2(b[1, 0] - b[0, 1], b[0, 0] + b[1, 1])
    scale = math.hypot(b[0, 0] + b[1, 1], b[1, 0] - b[0, 1]) / 2
    fitted = CameraCalibration(1.0 / scale, rotation, mirrored)._matrix()
    residual = image - plate @ fitted.T
    column_scales = np.linalg.norm(a, axis=0)
    return AxesFit(
        pixel_size_m=1.0 / scale,
        rotation_rad=rotation,
        mirrored=mirrored,
        residual_px=float(np.sqrt(np.mean(np.sum(residual**2, axis=1)))),
        anisotropy=float(abs(column_scales[0] - column_scales[1]) / column_scales.mean()),
    )


def rotation_centre(
    before_px: np.ndarray, after_px: np.ndarray, turns_rad: np.ndarray, mirrored: bool = False
) -> tuple[float, float, float]:
    """The θ centre O in the image from part centres before/after plate turns by ``turns_rad``.

    after − O = R(τ)(before − O), τ = the turn in the image (−turn when mirrored), so
    (I − R(τ))·O = after − R(τ)·before: linear in O, least squares over all turns.
    Returns (x_px, y_px, RMS residual px).
    """
    before = np.asarray(before_px, float).reshape(-1, 2)
    after = np.asarray(after_px, float).reshape(-1, 2)
    turns = np.atleast_1d(np.asarray(turns_rad, float))
    if not (before.shape == after.shape and before.shape[0] == turns.size >= 1):
        raise InputError("turns", "each θ turn needs one centre before and one after")
    if np.all(np.abs(np.sin(turns / 2)) < 1e-6):
        raise InputError("turns", "the θ turns must be non-zero")
    rows, rhs = [], []
    for p, q, turn in zip(before, after, turns, strict=True):
        tau = -turn if mirrored else turn
        c, s = math.cos(tau), math.sin(tau)
        r = np.array([[c, -s], [s, c]])
        rows.append(np.eye(2) - r)
        rhs.append(q - r @ p)
    m, y = np.vstack(rows), np.concatenate(rhs)
    origin, *_ = np.linalg.lstsq(m, y, rcond=None)
    residual = y - m @ origin
    return float(origin[0]), float(origin[1]), float(np.sqrt(np.mean(residual**2)) * math.sqrt(2))
