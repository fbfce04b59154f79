"""Writes docs/vision-error-budget.png: centre and angle error of `feeder vision locate` on rendered frames.

    python docs/vision_error_budget.py [--frames N]

A 300 px square (300 µm at 1 µm/px) on a 1024² frame, textured support, uneven
light, random subpixel poses; swept: the noise (fraction of the part/support
contrast, blur σ 1.5 px) and the blur (noise 2 %), each with the lossless frame
(PNG) and the same frame through JPEG at quality 90 (what /video.mjpg sends).
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from feeder.files import save_figure
from feeder.vision.locate import locate
from feeder.vision.model import PartTemplate, angle_difference
from firmware_sim.camera_render import CameraModel, FrameRenderer, PartInImage

OUT = Path(__file__).with_name("vision-error-budget.png")


def _rms(camera: CameraModel, frames: int, jpeg: bool, seed: int) -> tuple[float, float]:
    renderer = FrameRenderer(camera, seed=seed)
    rng = np.random.default_rng(seed)
    centre, angle = [], []
    for _ in range(frames):
        x, y = rng.uniform(300, 724, 2)
        a = rng.uniform(0, math.pi / 2)
        image = renderer.render([PartInImage(x, y, a, 300, 300)])
        if jpeg:
            image = cv2.imdecode(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])[1], 0)
        parts = locate(image, PartTemplate(300, 300)).parts
        if len(parts) != 1:
            continue
        centre.append(math.hypot(parts[0].x_px - x, parts[0].y_px - y))
        angle.append(math.degrees(angle_difference(parts[0].angle_rad, a, math.pi / 2)))
    return float(np.sqrt(np.mean(np.square(centre)))), float(np.sqrt(np.mean(np.square(angle))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    args = parser.parse_args()
    base = CameraModel(blur_px=1.5)
    noises = [0.005, 0.01, 0.02, 0.04, 0.08]
    blurs = [0.7, 1.0, 1.5, 2.5, 4.0]
    fig, axes = plt.subplots(2, 2, figsize=(9, 6.5), sharey="row")
    for column, (values, label, make) in enumerate(
        (
            (noises, "noise σ / contrast", lambda v: base.with_noise(v)),
            (blurs, "blur σ (px)", lambda v: replace(base, blur_px=v).with_noise(0.02)),
        )
    ):
        for jpeg, style in ((False, "o-"), (True, "s--")):
            results = [_rms(make(v), args.frames, jpeg, seed=k) for k, v in enumerate(values)]
            name = "JPEG q90 (MJPEG)" if jpeg else "lossless (PNG)"
            axes[0, column].plot(values, [r[0] for r in results], style, label=name)
            axes[1, column].plot(values, [r[1] for r in results], style, label=name)
        for row, target in ((0, 0.05), (1, 0.02)):
            axes[row, column].axhline(target, color="grey", lw=0.8, ls=":")
            axes[row, column].set_xscale("log")
            axes[row, column].set_xticks(values, [f"{v:g}" for v in values])
            axes[row, column].minorticks_off()
        axes[1, column].set_xlabel(label)
    axes[0, 0].set_ylabel("centre error RMS (px)")
    axes[1, 0].set_ylabel("angle error RMS (°)")
    axes[0, 0].legend()
    fig.suptitle(
        "feeder vision locate: 300 px square, 1024² frame, textured support "
        f"({args.frames} random poses per point; dotted: acceptance)",
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, OUT)
    print(OUT)


if __name__ == "__main__":
    main()
