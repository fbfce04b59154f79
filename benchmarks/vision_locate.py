"""Pose of one 300 px square part on a 1024² frame: ours vs a plain scikit-image pipeline.

Ours: :func:`feeder.vision.locate.locate` (4× shrunk Otsu + contours, subpixel
line fits on the four sides).  Baseline: what one writes with scikit-image
alone, at full resolution: ``threshold_otsu``, ``label``, ``regionprops``
(centroid and orientation of the thresholded mask).  Both on the same rendered
frames (blur σ 1.5 px, 2 % noise, textured support, uneven light).  Target:
``frames_per_s`` ≥ 200 (≤ 5 ms a frame); the centre and angle errors of both
are reported too (the mask's centroid is biased by the uneven light).
"""

from __future__ import annotations

import math

import numpy as np
from skimage.filters import threshold_otsu
from skimage.measure import label, regionprops
from timing import best_time

from feeder.vision.locate import locate
from feeder.vision.model import PartTemplate, angle_difference
from firmware_sim.camera_render import CameraModel, FrameRenderer, PartInImage


def _baseline(image: np.ndarray) -> tuple[float, float, float]:
    mask = image > threshold_otsu(image)
    region = max(regionprops(label(mask)), key=lambda r: r.area)
    y, x = region.centroid
    return float(x), float(y), float(-region.orientation + math.pi / 2)  # skimage: from the row axis


def run(quick: bool) -> dict[str, float | int]:
    frames = 10 if quick else 40
    renderer = FrameRenderer(CameraModel().with_noise(0.02), seed=0)
    rng = np.random.default_rng(0)
    template = PartTemplate(300, 300)
    ours_err, base_err, ours_ang, base_ang, images = [], [], [], [], []
    for _ in range(frames):
        x, y = rng.uniform(300, 724, 2)
        a = rng.uniform(0, math.pi / 2)
        image = renderer.render([PartInImage(x, y, a, 300, 300)])
        images.append(image)
        (part,) = locate(image, template).parts
        bx, by, ba = _baseline(image)
        ours_err.append(math.hypot(part.x_px - x, part.y_px - y))
        base_err.append(math.hypot(bx - x, by - y))
        ours_ang.append(math.degrees(angle_difference(part.angle_rad, a, math.pi / 2)))
        base_ang.append(math.degrees(angle_difference(ba, a, math.pi / 2)))
    repeats = 5 if quick else 20
    ours = min(best_time(lambda im=im: locate(im, template), repeats) for im in images[:5])
    baseline = min(best_time(lambda im=im: _baseline(im), max(2, repeats // 4)) for im in images[:5])
    rms = lambda values: float(math.sqrt(np.mean(np.square(values))))  # noqa: E731
    return {
        "ratio": baseline / ours,
        "frames_per_s": 1.0 / ours,
        "ours_ms": ours * 1e3,
        "baseline_ms": baseline * 1e3,
        "frames": frames,
        "ours_centre_rms_px": rms(ours_err),
        "baseline_centre_rms_px": rms(base_err),
        "ours_angle_rms_deg": rms(ours_ang),
        "baseline_angle_rms_deg": rms(base_ang),
    }
