"""Camera calibration from plate moves the amplifier makes: the stacks' DC offsets (DESIGN §10).

Each axis in turn holds its stack at +V in the offset mode and returns to 0 V; the plate, and
the parts stuck on it, move by the stack's static stroke: gain × V in x and y, a turn of
gain × V / lever arm about O in θ.  The offset is ramped in small increments: a jump plays at
the amplifier's slope limit like a flyback, and the parts slip (firmware_sim: a 100 V jump
leaves a part 3.9 µm behind a 7 µm plate move; 0.1 V increments hold it).  The camera's
frames before, at +V and after give each part's image move (at +V against the mean of before
and after, which cancels a slow drift); :func:`~feeder.vision.calibration.axes_from_moves`
fits scale, turn and mirroring to the x and y moves, and
:func:`~feeder.vision.calibration.rotation_centre` O in the image to the θ turn.

Units: m, px, rad, V, s.  The amplifiers and the sensor are opened and closed by the caller.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from feeder.drivers.amplifier import Amplifier
from feeder.drivers.sensor import PositionSensor
from feeder.errors import InputError
from feeder.vision.calibration import CameraCalibration, axes_from_moves, rotation_centre

log = logging.getLogger(__name__)


class Points(NamedTuple):
    """The parts' centres in the image (parts, 2) px and their standard errors (parts,) px."""

    mean: np.ndarray
    error: np.ndarray


SLIP_FRACTION = 0.03
"""A part whose image came back further than this fraction of the smallest move slipped: the
moves it gave are that much off (``slipped`` in the report)."""

FIRMWARE_SIM_GAIN_M_PER_V = 0.07e-6
"""firmware_sim's stacks: 14 µm at 200 V (:class:`feeder.plant.stack.StackParameters`)."""


@dataclass(frozen=True)
class OffsetMoves:
    """How the plate is moved: the offset (V), the stacks' static gain (m/V), the θ stack's lever
    arm (m), the ramp's increments (V) and pause after each (s), the wait before frames are
    averaged (s) and how many."""

    volts: float = 50.0
    stack_gain_m_per_v: float = FIRMWARE_SIM_GAIN_M_PER_V
    lever_arm_m: float = 1e-3
    increment_v: float = 0.05
    pause_s: float = 0.002
    settle_s: float = 0.3
    frames: int = 10
    frame_timeout_s: float = 2.0


def measure(
    amplifiers: Mapping[str, Amplifier],
    sensor: PositionSensor,
    located_with: CameraCalibration,
    moves: OffsetMoves,
    progress: Callable[[str], None] = lambda _: None,
) -> dict[str, Any]:
    """Move the plate on each of ``amplifiers``' axes (``x`` and ``y`` needed, ``theta`` for O)
    and fit the calibration; ``located_with`` is the calibration the sensor's poses were located
    with (they are mapped back to pixels).  Every axis is grounded before and after.

    Returns the fields of a ``feeder vision calibrate`` report (pixel size, rotation, mirroring,
    O when θ moved and its ``origin_uncertainty_px``, residuals) plus ``offset_v``, ``parts``,
    ``returned_px`` (how far the parts' images came back from where they started: a part that
    slipped does not) and ``slipped``.
    """
    if not {"x", "y"} <= set(amplifiers):
        raise InputError("axes", "the plate moves need the x and y axes ([plate] axes)")
    for amp in amplifiers.values():
        amp.ground()
    time.sleep(moves.settle_s)
    images: dict[str, tuple[Points, Points, Points]] = {}
    try:
        for axis in ("x", "y", "theta"):
            if axis not in amplifiers:
                continue
            amp = amplifiers[axis]
            before = _image_points(sensor, located_with, moves)
            progress(f"{axis}: offset 0 → {moves.volts:g} V")
            amp.ramp_offset(0.0, moves.volts, moves.increment_v, moves.pause_s)
            time.sleep(moves.settle_s)
            at = _image_points(sensor, located_with, moves)
            progress(f"{axis}: offset {moves.volts:g} → 0 V")
            amp.ramp_offset(moves.volts, 0.0, moves.increment_v, moves.pause_s)
            amp.ground()
            time.sleep(moves.settle_s)
            images[axis] = (before, at, _image_points(sensor, located_with, moves))
    finally:
        for amp in amplifiers.values():
            amp.ground()
    return _fit(images, moves)


def _image_points(sensor: PositionSensor, located_with: CameraCalibration, moves: OffsetMoves) -> Points:
    """Every part's centre in the image (parts, 2) px averaged over ``moves.frames`` frames taken
    after the settle (the first sample read may predate it), and that mean's standard error (px,
    per part; 0 from one frame)."""
    sensor.read(moves.frame_timeout_s)
    frames = []
    for _ in range(moves.frames):
        sample = sensor.read(moves.frame_timeout_s)
        frames.append([located_with.to_image(x, y) for x, y, _ in sample.poses])
    points = np.array(frames, dtype=float)
    spread = np.std(points, axis=0, ddof=1) if len(frames) > 1 else np.zeros(points.shape[1:])
    return Points(points.mean(axis=0), np.hypot(*spread.T) / math.sqrt(len(frames)))


def _fit(images: Mapping[str, tuple[Points, Points, Points]], moves: OffsetMoves) -> dict[str, Any]:
    stroke = moves.stack_gain_m_per_v * moves.volts
    plate, image = [], []
    for axis, direction in (("x", (stroke, 0.0)), ("y", (0.0, stroke))):
        before, at, after = images[axis]
        for move in at.mean - 0.5 * (before.mean + after.mean):
            plate.append(direction)
            image.append(move)
    fit = axes_from_moves(np.array(plate), np.array(image))
    report: dict[str, Any] = {
        "pixel_size_m": fit.pixel_size_m,
        "rotation_rad": fit.rotation_rad,
        "mirrored": fit.mirrored,
        "origin_x_px": None,
        "origin_y_px": None,
        "pixel_size_from_moves_m": fit.pixel_size_m,
        "moves_residual_px": fit.residual_px,
        "anisotropy": fit.anisotropy,
    }
    if "theta" in images:
        before, at, after = images["theta"]
        turn = stroke / moves.lever_arm_m
        start = 0.5 * (before.mean + after.mean)
        ox, oy, residual = rotation_centre(start, at.mean, np.full(len(start), turn), fit.mirrored)
        # a part's move is turn × its distance from O: an error e in the move puts O e / turn off;
        # e: the frames' scatter and the locator's bias, which the x and y moves' misfit shows
        move_error = np.sqrt(at.error**2 + 0.25 * (before.error**2 + after.error**2) + fit.residual_px**2)
        uncertainty = float(np.sqrt(np.mean(move_error**2)) / (turn * math.sqrt(len(start))))
        report.update(
            origin_x_px=ox, origin_y_px=oy, theta_residual_px=residual, origin_uncertainty_px=uncertainty
        )
    returned = max(float(np.max(np.hypot(*(b.mean - a.mean).T))) for a, _, b in images.values())
    smallest = min(float(np.min(np.hypot(*(at.mean - a.mean).T))) for a, at, _ in images.values())
    report.update(
        offset_v=moves.volts,
        plate_move_m=stroke,
        parts=len(images["x"][0].mean),
        returned_px=returned,
        slipped=returned > SLIP_FRACTION * smallest,
    )
    return report
