"""Subpixel edges: profiles across a part's outline, half-contrast crossings, line and circle fits.

A blurred straight edge between two flat levels crosses half contrast exactly
on the edge when the blur is symmetric, whatever the blur's width and the
light's level; so each profile (sampled across the expected edge) gives one
edge point, and a line fit through a few hundred of them on one side of the
part gives the side to a few hundredths of a pixel.  Neither OpenCV nor
scikit-image offers edge positions along chosen profiles (their Canny edges are
whole pixels), so the profile sampling and the crossing search are written here;
the fits themselves are OpenCV's (``cv2.fitLine``, with one outlier clip) and
scikit-image's (``CircleModel``, total least squares).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from skimage.measure import CircleModel

LEVEL_PX = 1.5  # length at each end of a profile that gives its inner / outer level
FIT_SAMPLES = 4  # samples around the crossing in its local line fit


def sample(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a float32 image at (x, y) (pixels, image convention).

    By hand because ``cv2.remap`` rounds positions to 1/32 px (a systematic
    ±0.016 px on a side parallel to the pixel grid) and
    ``scipy.ndimage.map_coordinates`` is several times slower.
    Positions outside the image take the border values.
    """
    h, w = image.shape
    x = np.clip(x, 0.0, w - 1.000001)
    y = np.clip(y, 0.0, h - 1.000001)
    x0 = x.astype(np.intp)
    y0 = y.astype(np.intp)
    fx = (x - x0).astype(np.float32)
    fy = (y - y0).astype(np.float32)
    flat = image.ravel()
    i = y0 * w + x0
    top = flat[i]
    top += fx * (flat[i + 1] - top)
    bottom = flat[i + w]
    bottom += fx * (flat[i + w + 1] - bottom)
    top += fy * (bottom - top)
    return top


@dataclass(frozen=True)
class Crossings:
    """Per profile: the edge's offset along the profile (px, 0 = the profile's middle), whether
    it was found, the inner and outer levels, and the edge slope as a blur σ (px)."""

    offset_px: np.ndarray
    valid: np.ndarray
    inner: np.ndarray
    outer: np.ndarray
    blur_px: np.ndarray


def crossings(profiles: np.ndarray, step_px: float, min_contrast: float) -> Crossings:
    """Half-contrast crossing of each row of ``profiles`` (inside → outside, ``step_px`` apart).

    Levels are the means of the first and last LEVEL_PX of each profile; the
    crossing nearest the middle is refined by a line fit through the
    FIT_SAMPLES samples around it.  A profile whose level difference is below
    ``min_contrast`` or with no crossing is not valid.
    """
    m = profiles.shape[1]
    k = max(1, round(LEVEL_PX / step_px) + 1)
    inner = profiles[:, :k].mean(axis=1)
    outer = profiles[:, -k:].mean(axis=1)
    contrast = outer - inner
    valid = np.abs(contrast) >= min_contrast
    safe = np.where(valid, contrast, 1.0)
    d = (profiles - ((inner + outer) / 2)[:, None]) / safe[:, None]  # −½ inside → +½ outside
    up = (d[:, :-1] < 0) & (d[:, 1:] >= 0)
    middle = (m - 1) / 2
    nearness = up * (m - np.abs(np.arange(m - 1) + 0.5 - middle))[None, :]
    j = np.argmax(nearness, axis=1)
    valid &= up.any(axis=1)
    first = np.clip(j - (FIT_SAMPLES // 2 - 1), 0, m - FIT_SAMPLES)
    window = first[:, None] + np.arange(FIT_SAMPLES)[None, :]
    values = np.take_along_axis(d, window, axis=1)
    s = window * step_px
    s_mean = s.mean(axis=1)
    v_mean = values.mean(axis=1)
    ds = s - s_mean[:, None]
    slope = (ds * (values - v_mean[:, None])).sum(axis=1) / (ds * ds).sum(axis=1)
    valid &= slope > 0
    slope = np.where(valid, slope, 1.0)
    at = s_mean - v_mean / slope
    valid &= np.abs(at - (j + 0.5) * step_px) <= step_px
    return Crossings(at - middle * step_px, valid, inner, outer, 1.0 / (slope * math.sqrt(2 * math.pi)))


def fit_offset_line(t: np.ndarray, offset: np.ndarray) -> tuple[float, float, float]:
    """Line offset = a + b·t by ``cv2.fitLine`` (least squares), refitted once without the points
    further than 3 RMS from the first fit; returns (a, b, RMS residual of the points kept)."""
    points = np.column_stack([t, offset]).astype(np.float32)
    for _ in range(2):
        vx, vy, x0, y0 = cv2.fitLine(points, cv2.DIST_L2, 0, 0.01, 0.01).ravel()
        b = float(vy / vx) if abs(vx) > 1e-9 else 0.0
        a = float(y0 - b * x0)
        residual = points[:, 1] - (a + b * points[:, 0])
        rms = float(np.sqrt(np.mean(residual**2)))
        keep = np.abs(residual) <= max(3 * rms, 0.05)
        if keep.all() or keep.sum() < 3:
            break
        points = points[keep]
    return a, b, rms


@dataclass(frozen=True)
class RectangleFit:
    """A rectangle's outline from four fitted sides (pixels, radians; angle of the first side pair)."""

    x_px: float
    y_px: float
    angle_rad: float
    length_px: float
    width_px: float
    edge_rms_px: float
    valid_fraction: float
    inner_level: float
    outer_level: float
    blur_px: float


MIN_PROFILES = 5
"""Profiles across a side at least, closer than ``spacing`` on a short side (an 80 µm part at
2.7 µm/px has 30 px sides: 8 px apart, a side had one profile and the part was refused)."""
MIN_REACH_PX = 2.0
"""A side whose corners leave less than ± this to profile gets one profile (refused: too few)."""


def _profile_plan(half_extent: float, margin: float, spacing: float) -> np.ndarray:
    reach = half_extent - margin
    if reach < MIN_REACH_PX:
        return np.zeros(1)
    count = max(MIN_PROFILES, int(2 * reach / spacing) + 1)
    return np.linspace(-reach, reach, count)


def refine_rectangle(
    image: np.ndarray,
    x: float,
    y: float,
    angle: float,
    length: float,
    width: float,
    min_contrast: float,
    passes: tuple[tuple[float, float], ...] = ((10.0, 8.0), (0.0, 2.0)),
    step_px: float = 0.5,
) -> RectangleFit | None:
    """Refine a rough rectangle pose by subpixel line fits on its four sides.

    Each pass samples profiles across every side (corners left out by 4σ of the
    blur), fits a line per side, and moves the centre to the mid-lines and the
    angle to the length-weighted mean tilt of the sides.  ``passes`` gives each
    pass' profile half-length (px; 0 = 3σ of the blur measured in the pass
    before + 1.5 px) and the spacing of profiles along a side (px).
    """
    blur = 1.5
    fit: RectangleFit | None = None
    for half_length, spacing in passes:
        h = half_length if half_length > 0 else float(np.clip(3 * blur + 1.5, 4.0, 20.0))
        s = np.arange(-round(h / step_px), round(h / step_px) + 1) * step_px  # symmetric: 0 in the middle
        c, si = math.cos(angle), math.sin(angle)
        e1, e2 = np.array([c, si]), np.array([-si, c])
        margin = 4 * blur + 2 + (0.1 * max(length, width) if fit is None else 0.0)
        sides = [
            (e1, e2, length / 2, width / 2),
            (-e1, e2, length / 2, width / 2),
            (e2, e1, width / 2, length / 2),
            (-e2, e1, width / 2, length / 2),
        ]
        plans = [_profile_plan(extent, margin, spacing) for _, _, _, extent in sides]
        bx, by, nx, ny = [], [], [], []
        for (normal, tangent, distance, _), t in zip(sides, plans, strict=True):
            bx.append(x + distance * normal[0] + t * tangent[0])
            by.append(y + distance * normal[1] + t * tangent[1])
            nx.append(np.full(t.size, normal[0]))
            ny.append(np.full(t.size, normal[1]))
        base_x, base_y = np.concatenate(bx), np.concatenate(by)
        norm_x, norm_y = np.concatenate(nx), np.concatenate(ny)
        profiles = sample(
            image,
            base_x[:, None] + s[None, :] * norm_x[:, None],
            base_y[:, None] + s[None, :] * norm_y[:, None],
        )
        found = crossings(profiles, step_px, min_contrast)
        offsets, tilts, weights, square_residuals, start = [], [], [], [], 0
        for (normal, tangent, _, _), t in zip(sides, plans, strict=True):
            part = slice(start, start + t.size)
            start += t.size
            ok = found.valid[part]
            if ok.sum() < 3:
                return None
            a, b, rms = fit_offset_line(t[ok], found.offset_px[part][ok])
            sense = tangent[0] * normal[1] - tangent[1] * normal[0]
            offsets.append(a)
            tilts.append(sense * math.atan(b))
            weights.append(float(np.sum(t[ok] ** 2)))
            square_residuals.append(rms**2 * ok.sum())
        shift_1 = (offsets[0] - offsets[1]) / 2
        shift_2 = (offsets[2] - offsets[3]) / 2
        x += shift_1 * e1[0] + shift_2 * e2[0]
        y += shift_1 * e1[1] + shift_2 * e2[1]
        length += offsets[0] + offsets[1]
        width += offsets[2] + offsets[3]
        angle += float(np.average(tilts, weights=weights))
        valid = found.valid
        blur = float(np.clip(found.blur_px[valid], 0.3, 10.0).mean())
        fit = RectangleFit(
            x,
            y,
            angle,
            length,
            width,
            edge_rms_px=math.sqrt(sum(square_residuals) / valid.sum()),
            valid_fraction=float(valid.mean()),
            inner_level=float(found.inner[valid].mean()),
            outer_level=float(found.outer[valid].mean()),
            blur_px=blur,
        )
    return fit


@dataclass(frozen=True)
class CircleFit:
    """A disc's outline from a circle fit to its subpixel edge points (pixels)."""

    x_px: float
    y_px: float
    radius_px: float
    edge_rms_px: float
    valid_fraction: float
    inner_level: float
    outer_level: float


def refine_circle(
    image: np.ndarray,
    x: float,
    y: float,
    radius: float,
    min_contrast: float,
    passes: tuple[float, ...] = (10.0, 6.0),
    step_px: float = 0.5,
) -> CircleFit | None:
    """Refine a rough disc by radial profiles and a total-least-squares circle (scikit-image)."""
    fit: CircleFit | None = None
    for h in passes:
        count = int(np.clip(2 * math.pi * radius, 32, 2048))
        theta = np.linspace(0, 2 * math.pi, count, endpoint=False)
        nx, ny = np.cos(theta), np.sin(theta)
        s = np.arange(-round(h / step_px), round(h / step_px) + 1) * step_px  # symmetric: 0 in the middle
        r = radius + s[None, :]
        profiles = sample(image, x + r * nx[:, None], y + r * ny[:, None])
        found = crossings(profiles, step_px, min_contrast)
        ok = found.valid
        if ok.sum() < 8:
            return None
        edge_r = radius + found.offset_px[ok]
        points = np.column_stack([x + edge_r * nx[ok], y + edge_r * ny[ok]])
        model = CircleModel.from_estimate(points)
        if not model:
            return None
        (x, y), radius = (float(v) for v in model.center), float(model.radius)
        rms = float(np.sqrt(np.mean(model.residuals(points) ** 2)))
        fit = CircleFit(
            x,
            y,
            radius,
            rms,
            float(ok.mean()),
            float(np.median(found.inner[ok])),
            float(np.median(found.outer[ok])),
        )
    return fit
