"""Microscope frames of the world: parts on a textured support, as a camera sees them.

Scene (in units of the sensor's full well at exposure 1): the support is
``support_level`` × (1 + texture) with a smooth random texture (RMS ``texture``,
correlation ``texture_px``), parts are ``part_level`` (brighter or darker than
the support: both polarities), the orientation mark is ``mark_level``; all
multiplied by an uneven illumination (quadratic fall-off ``vignetting`` to the
corners plus a linear ``tilt`` across x).  Optics: a Gaussian defocus blur of σ
``blur_px``.  Sensor: ``exposure`` scales the signal, shot noise (Poisson,
Gaussian approximation, ``full_well_e`` electrons at full scale) and read noise
(``read_noise_e``), clipped at full scale and quantised to ``bits`` (8 → uint8,
12 → uint16 0..4095).

Geometry follows feeder.vision.model (image convention, orientation mark).  A
part is drawn as the samples of its outline already seen through a Gaussian of
σ = min(``blur_px``, 1 px) (for a rectangle the product of two Φ(d/σ) along its
own axes, which is exact), then blurred by the rest of ``blur_px`` on the pixel
grid.  Drawing a sharp outline (pixel area coverage) and blurring that instead
aliases: the edge would seem shifted by up to 0.1 px depending on its subpixel
phase, which is not what a lens and a sensor do.  ``blur_px`` is the σ of the
whole point spread, the pixel's own integration included.

Speed: the blurred support and the illumination are rendered once, and so are
:data:`BACKGROUND_FRAMES` noisy, quantised frames of the bare support; a frame
copies the next of these and redraws (blurs, adds noise to, quantises) only a
box around each part.  The noise comes from a bank of normal deviates two
frames long read at a random offset (independent from pixel to pixel; drawing
4 M deviates per frame would cost more than the whole frame).  Away from the
parts the noise repeats every :data:`BACKGROUND_FRAMES` frames.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.special import ndtr

from feeder.vision.model import MARK_OFFSET, MARK_RADIUS

EDGE_SIGMA_PX = 1.0  # part outlines are drawn already blurred by this much (see the module doc)
BACKGROUND_FRAMES = 4
"""Noisy frames of the bare support made once and used in turn (two frames in a row differ)."""


@dataclass(frozen=True)
class CameraModel:
    """Optics, lighting and sensor of the simulated microscope camera (see the module doc)."""

    width_px: int = 1024
    height_px: int = 1024
    blur_px: float = 1.5
    support_level: float = 0.3
    part_level: float = 0.7
    mark_level: float = 0.3
    texture: float = 0.05
    texture_px: float = 2.0
    vignetting: float = 0.15
    tilt: float = 0.05
    exposure: float = 1.0
    full_well_e: float = 10_000.0
    read_noise_e: float = 10.0
    bits: int = 8

    def __post_init__(self) -> None:
        if self.bits not in (8, 12):
            raise ValueError(f"bits must be 8 or 12, got {self.bits}")
        if self.width_px < 16 or self.height_px < 16:
            raise ValueError("the frame must be at least 16 × 16 pixels")

    @property
    def full_scale(self) -> int:
        return (1 << self.bits) - 1

    def with_noise(self, fraction_of_contrast: float) -> CameraModel:
        """This camera with the full well that gives noise σ = ``fraction_of_contrast`` × the
        part/support contrast at the mid level (read noise kept)."""
        level = self.exposure * (self.part_level + self.support_level) / 2
        target = fraction_of_contrast * self.exposure * abs(self.part_level - self.support_level)
        read2 = self.read_noise_e**2
        full_well = (level + math.sqrt(level**2 + 4 * target**2 * read2)) / (2 * target**2)
        return replace(self, full_well_e=full_well)

    def noise_at(self, level: float) -> float:
        """Noise σ (full-scale units) of a pixel at scene ``level``."""
        electrons = level * self.exposure * self.full_well_e
        return math.sqrt(electrons + self.read_noise_e**2) / self.full_well_e


@dataclass(frozen=True)
class PartInImage:
    """A part as the camera sees it: centre (px), angle of its L side (rad, +x towards +y),
    footprint L × W (px; a disc: diameter), shape, mark, and an optional own brightness."""

    x_px: float
    y_px: float
    angle_rad: float
    length_px: float
    width_px: float
    disc: bool = False
    mark: bool = False
    level: float | None = None

    def reach_px(self) -> float:
        """Radius of a circle around the centre that holds the whole part."""
        return 0.5 * (self.length_px if self.disc else math.hypot(self.length_px, self.width_px))


class FrameRenderer:
    """Renders frames of one camera; the static background is built once here."""

    def __init__(self, camera: CameraModel, seed: int = 0) -> None:
        self.camera = camera
        rng = np.random.default_rng(seed)
        h, w = camera.height_px, camera.width_px
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((x - (w - 1) / 2) ** 2 + (y - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2)
        self.illumination = (1.0 - camera.vignetting * r2 + camera.tilt * (x / (w - 1) - 0.5)).astype(
            np.float32
        )
        grain: np.ndarray = rng.standard_normal((h, w)).astype(np.float32)
        if camera.texture_px > 0:
            grain = cv2.GaussianBlur(grain, (0, 0), camera.texture_px)
        grain *= camera.texture / max(float(grain.std()), 1e-12)
        self.support_sharp = (self.illumination * camera.support_level * (1.0 + grain)).astype(np.float32)
        self.background = self._blur(self.support_sharp) * np.float32(camera.exposure)
        self._bank = rng.standard_normal(2 * h * w, dtype=np.float32)
        self._rng = np.random.default_rng(seed + 1)
        self._backgrounds: list[np.ndarray] = []
        self._frame = 0
        self._edge_sigma = min(camera.blur_px, EDGE_SIGMA_PX)
        self._rest_sigma = math.sqrt(max(camera.blur_px**2 - self._edge_sigma**2, 0.0))

    def _blur(self, image: np.ndarray) -> np.ndarray:
        if self.camera.blur_px <= 0:
            return image.copy()
        return cv2.GaussianBlur(image, (0, 0), self.camera.blur_px, borderType=cv2.BORDER_REFLECT)

    def _noise_sigma(self, signal: np.ndarray) -> np.ndarray:
        """Shot + read noise σ (full-scale units) of an exposed signal (full-scale units)."""
        c = self.camera
        electrons = np.maximum(signal, 0) * np.float32(c.full_well_e) + np.float32(c.read_noise_e**2)
        return (np.sqrt(electrons) / np.float32(c.full_well_e)).astype(np.float32)

    def signal(self, parts: Sequence[PartInImage]) -> np.ndarray:
        """The noiseless exposed image (float32, full-scale units), background copied, parts redrawn."""
        image = self.background.copy()
        for box in self._boxes(parts):
            y0, y1, x0, x1 = box
            image[y0:y1, x0:x1] += self._part_delta(parts, box)
        return image

    def render(self, parts: Sequence[PartInImage]) -> np.ndarray:
        """One frame: uint8 (8 bits) or uint16 holding 0..4095 (12 bits)."""
        c = self.camera
        h, w = c.height_px, c.width_px
        if not self._backgrounds:  # the noisy, quantised bare support: a few frames, made once
            self._backgrounds = [
                self._quantise(self._noisy(self.background)) for _ in range(BACKGROUND_FRAMES)
            ]
        image = self._backgrounds[self._frame % BACKGROUND_FRAMES].copy()
        self._frame += 1
        for box in self._boxes(parts):
            y0, y1, x0, x1 = box
            roi = self.background[y0:y1, x0:x1] + self._part_delta(parts, box)
            image[y0:y1, x0:x1] = self._quantise(self._noisy(roi))
        assert image.shape == (h, w)
        return image

    def _noisy(self, signal: np.ndarray) -> np.ndarray:
        """``signal`` (exposed, full-scale units) plus shot and read noise from the deviate bank."""
        offset = int(self._rng.integers(0, self._bank.size - signal.size))
        deviates = self._bank[offset : offset + signal.size].reshape(signal.shape)
        image: np.ndarray = cv2.multiply(self._noise_sigma(signal), deviates)
        cv2.add(image, signal, dst=image)
        return image

    def _quantise(self, image: np.ndarray) -> np.ndarray:
        """Full-scale float → the sensor's codes (clipped at 0 and full scale)."""
        c = self.camera
        np.maximum(image, np.float32(0), out=image)
        if c.bits == 8:
            return cv2.convertScaleAbs(image, alpha=c.full_scale)
        np.multiply(image, np.float32(c.full_scale), out=image)
        np.minimum(image, np.float32(c.full_scale), out=image)
        image += np.float32(0.5)
        return image.astype(np.uint16)

    def _boxes(self, parts: Sequence[PartInImage]) -> list[tuple[int, int, int, int]]:
        """Boxes (y0, y1, x0, x1) around the parts, merged where they overlap."""
        c = self.camera
        margin = 4.0 * c.blur_px + 2.0
        boxes: list[list[int]] = []
        for part in parts:
            reach = part.reach_px() + margin
            box = [
                max(0, math.floor(part.y_px - reach)),
                min(c.height_px, math.ceil(part.y_px + reach) + 1),
                max(0, math.floor(part.x_px - reach)),
                min(c.width_px, math.ceil(part.x_px + reach) + 1),
            ]
            if box[0] >= box[1] or box[2] >= box[3]:
                continue
            merged = True
            while merged:
                merged = False
                for other in boxes:
                    if box[0] < other[1] and other[0] < box[1] and box[2] < other[3] and other[2] < box[3]:
                        boxes.remove(other)
                        box = [
                            min(box[0], other[0]),
                            max(box[1], other[1]),
                            min(box[2], other[2]),
                            max(box[3], other[3]),
                        ]
                        merged = True
                        break
            boxes.append(box)
        return [(b[0], b[1], b[2], b[3]) for b in boxes]

    def _part_delta(self, parts: Sequence[PartInImage], box: tuple[int, int, int, int]) -> np.ndarray:
        """Blurred (scene with the parts − bare support) inside ``box``, exposed."""
        c = self.camera
        y0, y1, x0, x1 = box
        support = self.support_sharp[y0:y1, x0:x1]
        illumination = self.illumination[y0:y1, x0:x1]
        scene = support.copy()
        xs = np.arange(x0, x1, dtype=np.float32)
        ys = np.arange(y0, y1, dtype=np.float32)
        for part in parts:  # later parts lie on top of earlier ones
            if not (x0 <= part.x_px < x1 and y0 <= part.y_px < y1):
                continue
            cover = _coverage(part, xs, ys, self._edge_sigma)
            level = c.part_level if part.level is None else part.level
            scene += cover * (illumination * np.float32(level) - scene)
            if part.mark:
                rows, cols, mark = _mark(part, xs, ys, self._edge_sigma)
                scene[rows, cols] += (
                    cover[rows, cols] * illumination[rows, cols] * mark * np.float32(c.mark_level - level)
                )
        delta = scene - support
        if self._rest_sigma > 0:
            delta = cv2.GaussianBlur(delta, (0, 0), self._rest_sigma, borderType=cv2.BORDER_REFLECT)
        delta *= np.float32(c.exposure)
        return delta


def _edge(distance_inside: np.ndarray, sigma: float) -> np.ndarray:
    """A straight edge seen through a Gaussian of σ ``sigma`` px, at pixel centres ``distance_inside`` px
    inside it: Φ(d/σ) within 4σ of the edge (elsewhere 0 or 1); σ = 0: the pixel's area coverage."""
    if sigma <= 0:
        return np.clip(distance_inside + np.float32(0.5), 0, 1)
    out = (distance_inside > 0).astype(np.float32)
    band = np.abs(distance_inside) < 4 * sigma
    out[band] = ndtr(distance_inside[band] / sigma)
    return out


def _part_axes(part: PartInImage, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres of the grid xs × ys in the part's own axes (u along L, v along W), px."""
    cos, sin = np.float32(math.cos(part.angle_rad)), np.float32(math.sin(part.angle_rad))
    dx = (xs - np.float32(part.x_px))[None, :]
    dy = (ys - np.float32(part.y_px))[:, None]
    return dx * cos + dy * sin, dy * cos - dx * sin


def _coverage(part: PartInImage, xs: np.ndarray, ys: np.ndarray, sigma: float) -> np.ndarray:
    """The part on the grid xs × ys, pre-blurred by σ ``sigma`` px (0..1)."""
    u, v = _part_axes(part, xs, ys)
    if part.disc:
        return _edge(np.float32(part.length_px / 2) - np.sqrt(u * u + v * v), sigma)
    return _edge(np.float32(part.length_px / 2) - np.abs(u), sigma) * _edge(
        np.float32(part.width_px / 2) - np.abs(v), sigma
    )


def _mark(part: PartInImage, xs: np.ndarray, ys: np.ndarray, sigma: float) -> tuple[slice, slice, np.ndarray]:
    """The orientation mark (0..1) on the part of the grid xs × ys around it: (rows, columns, values)."""
    if part.disc:
        offset, radius = part.length_px / 4, MARK_RADIUS * part.length_px
    else:
        offset, radius = MARK_OFFSET * part.length_px, MARK_RADIUS * min(part.length_px, part.width_px)
    cx = part.x_px + offset * math.cos(part.angle_rad)
    cy = part.y_px + offset * math.sin(part.angle_rad)
    reach = radius + 4 * sigma + 1
    cols = slice(int(np.searchsorted(xs, cx - reach)), int(np.searchsorted(xs, cx + reach)))
    rows = slice(int(np.searchsorted(ys, cy - reach)), int(np.searchsorted(ys, cy + reach)))
    dx = (xs[cols] - np.float32(cx))[None, :]
    dy = (ys[rows] - np.float32(cy))[:, None]
    return rows, cols, _edge(np.float32(radius) - np.sqrt(dx * dx + dy * dy), sigma)
