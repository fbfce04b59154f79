"""A 1024² microscope frame with one part: ours vs rendering the whole frame each time.

Ours: :class:`firmware_sim.camera_render.FrameRenderer` (static blurred support
and its noise σ made once; per frame: a noise bank read at a random offset,
only a box around the part redrawn and blurred).  Baseline: the same scene
drawn and blurred over the whole frame, with fresh normal deviates for the
noise (the straightforward way).  Target: ≤ 5 ms a frame.
"""

from __future__ import annotations

import numpy as np
from timing import best_time

from firmware_sim.camera_render import CameraModel, FrameRenderer, PartInImage


def _whole_frame(renderer: FrameRenderer, parts: list[PartInImage], rng: np.random.Generator) -> np.ndarray:
    c = renderer.camera
    signal = renderer.background + renderer._part_delta(parts, (0, c.height_px, 0, c.width_px))
    noisy = signal + renderer._noise_sigma(signal) * rng.standard_normal(signal.shape, dtype=np.float32)
    return np.clip(np.rint(noisy * c.full_scale), 0, c.full_scale).astype(np.uint8)


def run(quick: bool) -> dict[str, float | int]:
    renderer = FrameRenderer(CameraModel().with_noise(0.02), seed=0)
    parts = [PartInImage(500.3, 480.7, 0.4, 300, 300, mark=True)]
    rng = np.random.default_rng(0)
    c = renderer.camera
    whole = renderer.background + renderer._part_delta(parts, (0, c.height_px, 0, c.width_px))
    difference = float(np.max(np.abs(renderer.signal(parts) - whole))) * c.full_scale
    if difference > 0.01:
        raise AssertionError(f"redrawing a box differs from the whole frame by {difference:.3g} DN")
    repeats = 10 if quick else 50
    ours = best_time(lambda: renderer.render(parts), repeats)
    baseline = best_time(lambda: _whole_frame(renderer, parts, rng), max(3, repeats // 10))
    return {
        "ratio": baseline / ours,
        "ms_per_frame": ours * 1e3,
        "baseline_ms_per_frame": baseline * 1e3,
        "frame_px": renderer.camera.width_px * renderer.camera.height_px,
        "max_signal_difference_dn": difference,
    }
