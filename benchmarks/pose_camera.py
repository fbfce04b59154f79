"""The planar world's camera, 2048² at 2.5 µm/px with two parts: locating and serving a frame.

Ours: :class:`feeder.drivers.pose_camera.CameraPoseSensor`'s tracking step, a locate in a
region around each part.  Baseline: the whole-frame search it falls back to when acquiring.
Both on the BGR frame an MJPEG stream decodes to.  The subpixel edge fits are the same in
both and dominate; the region saves the grey conversion and the coarse search of 4 MP.
Also: the simulated camera's cost per frame, render + JPEG encode (what 30 frames/s needs:
under 33 ms on one core), and the located poses' error against the rendered truth.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from timing import best_time

from feeder.drivers.pose_camera import CameraPoseSensor, part_template
from feeder.pose import pose_error
from feeder.vision.calibration import CameraCalibration
from feeder.vision.locate import locate
from firmware_sim.camera_http import JPEG_QUALITY
from firmware_sim.camera_render import CameraModel, FrameRenderer, PartInImage

SIDE_PX = 2048
PIXEL_M = 2.5e-6
PART_M = 300e-6
POSES = ((-1.0e-3, 0.4e-3, 0.3), (1.2e-3, -0.7e-3, 1.1))


def run(quick: bool) -> dict[str, float | int]:
    calibration = CameraCalibration(PIXEL_M, origin_x_px=(SIDE_PX - 1) / 2, origin_y_px=(SIDE_PX - 1) / 2)
    template = part_template(PART_M, PART_M, calibration)
    renderer = FrameRenderer(CameraModel(width_px=SIDE_PX, height_px=SIDE_PX), seed=0)
    side = PART_M / PIXEL_M
    parts = [
        PartInImage(*calibration.to_image(x, y), calibration.angle_to_image(psi), side, side)
        for x, y, psi in POSES
    ]
    image = renderer.render(parts)
    repeats = 5 if quick else 20
    render_s = best_time(lambda: renderer.render(parts), repeats)
    encode_s = best_time(
        lambda: cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]), repeats
    )

    frame = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)  # what an MJPEG stream decodes to
    full = locate(frame, template).parts
    if len(full) != len(POSES):
        raise AssertionError(f"{len(full)} parts located, {len(POSES)} rendered")
    sensor = CameraPoseSensor.__new__(CameraPoseSensor)  # the tracking step alone, no thread
    sensor.template, sensor.polarity = template, "bright"
    sensor.reach_px, sensor.roi_margin_px = side / math.sqrt(2), side / math.sqrt(2)
    regions = lambda: [sensor._in_region(frame, d) for d in full]  # noqa: E731
    region_s = best_time(regions, repeats)
    full_s = best_time(lambda: locate(frame, template), max(3, repeats // 4))
    tracked = [d for d in regions() if d is not None]
    if len(tracked) != len(POSES):
        raise AssertionError("a part was lost in its region")
    errors = []
    for found, (x, y, psi) in zip(sorted(tracked, key=lambda d: d.x_px), POSES, strict=True):
        pose = (*calibration.to_plate(found.x_px, found.y_px), calibration.angle_to_plate(found.angle_rad))
        errors.append(pose_error(pose, (x, y, psi), template.symmetry_rad))
    return {
        "ratio": full_s / region_s,
        "region_locate_ms": region_s * 1e3,
        "full_frame_locate_ms": full_s * 1e3,
        "render_ms": render_s * 1e3,
        "jpeg_encode_ms": encode_s * 1e3,
        "camera_fps_one_core": 1.0 / (render_s + encode_s),
        "max_error_m": max(e[0] for e in errors),
        "max_error_deg": math.degrees(max(e[1] for e in errors)),
        "frame_px": int(np.prod(image.shape)),
    }
