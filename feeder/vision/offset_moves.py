"""Camera calibration from plate moves the amplifier makes: the stacks' DC offsets (DESIGN §10).

Each axis in turn holds its stack at +V in the offset mode and returns to 0 V; the plate, and
the parts stuck on it, move by the stack's static stroke: gain × V in x and y, a turn about O
in θ.  The camera's frames before, at +V and after give each part's image move (at +V against
the mean of before and after, which cancels a slow drift);
:func:`~feeder.vision.calibration.axes_from_moves` fits scale, turn and mirroring to the x and
y moves, :func:`~feeder.vision.calibration.rotation_centre` O in the image to the θ move.  The
θ turn comes from the parts themselves when two or more are seen (the line between them turns
by it), so O does not rest on the stack's gain or the lever arm; from one part it is
gain × V / lever arm.

The offset is ramped, never jumped: a new level plays at the amplifier's slope limit like a
flyback, and the parts slip (firmware_sim: a 100 V jump leaves a part 3.9 µm behind a 7 µm
plate move).  The ramp up goes in ``increment_v`` steps, the ramp down in half that: a slip
on the way up that the finer way down does not repeat leaves the parts away from where they
started (``returned_px``, ``slipped``; a slip repeated in both directions would cancel).  In θ
a part r from O feels the plate's turn r / lever arm times as hard as a translation: the θ
increment shrinks by that factor (r from the configured calibration, with a margin).

Units: m, px, rad, V, s.  The amplifiers and the sensor are opened and closed by the caller.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from feeder.drivers.amplifier import Amplifier, AmplifierError
from feeder.drivers.sensor import PositionSensor
from feeder.errors import FeederError, InputError
from feeder.reading_noise import reading_noise
from feeder.vision.calibration import CameraCalibration, axes_from_moves, rotation_centre

log = logging.getLogger(__name__)

FIRMWARE_SIM_GAIN_M_PER_V = 0.07e-6
"""firmware_sim's stacks: 14 µm at 200 V (:class:`feeder.plant.stack.StackParameters`)."""

SLIP_FRACTION = 0.01
"""Parts whose images came back further than this fraction of their axis' smallest move (and
beyond the frames' noise) slipped: the moves they gave are off by about as much (the default of
``OffsetMoves.slip_fraction``)."""
SLIP_FRACTION_RANGE = (1e-3, 0.2)
"""The slip fraction a user may set (``--slip-fraction``)."""

GAIN_UNCERTAINTY = 0.05
"""A stack's stroke per volt (and a lever arm) is known to a few percent: O from one part, whose
turn is assumed from them, is this fraction of the part's distance from O uncertain besides."""

SCALE_WARNING = 0.1
"""The moves' pixel size and the one the parts were located with (configured or stored) differ
by more than this fraction: say so (a wrong stack gain, or the moves not seen)."""

RADIUS_MARGIN = 1.25
"""The parts' distances from O, measured with the configured calibration, are taken this much
larger for the θ increment (the configured O may be off)."""


class MovesStopped(FeederError):
    """The moves were stopped (``stop`` set): every axis grounded, nothing measured."""


STEADY_FRAMES = 6
"""The image is steady when the two halves of the last ``max(frames, STEADY_FRAMES)`` frames
show every part at the same place: within :data:`STEADY_ERRORS` standard errors of the
difference of their means (from the frames' noise,
:func:`~feeder.reading_noise.reading_noise`), ..."""

STEADY_ERRORS = 3.0
"""(a still image seen as moving costs a frame; a moving one seen as still biases the move)"""

STEADY_PX = 0.01
"""... or this much (px: a sub-pixel locator's quantisation), ..."""

STEADY_FRACTION = 0.005
"""... or this fraction of the part's move (from before the offset to at it, or from at it
back; none for the points before a move: a stack's creep)."""


class Points(NamedTuple):
    """The parts' centres in the image (parts, 2) px, their standard errors (parts,) px, and how
    far the image was still moving when the wait for a steady one ran out (px; 0 when steady)."""

    mean: np.ndarray
    error: np.ndarray
    unsteady_px: float = 0.0


@dataclass(frozen=True)
class OffsetMoves:
    """How the plate is moved: the offset (V), the stacks' static gain (m/V), the θ stack's lever
    arm (m), the ramp's increments (V) and pause after each (s), the wait before frames are
    read (s), how many are averaged, how long frames are read beyond those for a steady
    image (s), and how far (a fraction of the smallest move) the parts may come back off their
    start before they count as slipped (a real stack's creep leaves ~1 % of its stroke)."""

    volts: float = 100.0
    stack_gain_m_per_v: float = FIRMWARE_SIM_GAIN_M_PER_V
    lever_arm_m: float = 1e-3
    increment_v: float = 0.05
    pause_s: float = 0.002
    settle_s: float = 0.3
    frames: int = 10
    frame_timeout_s: float = 2.0
    steady_timeout_s: float = 10.0
    slip_fraction: float = SLIP_FRACTION


def measure(
    amplifiers: Mapping[str, Amplifier],
    sensor: PositionSensor,
    located_with: CameraCalibration,
    moves: OffsetMoves,
    progress: Callable[[str], None] = lambda _: None,
    stop: threading.Event | None = None,
) -> dict[str, Any]:
    """Move the plate on each of ``amplifiers``' axes (``x`` and ``y`` needed, ``theta`` for O)
    and fit the calibration; ``located_with`` is the calibration the sensor's poses were located
    with (they are mapped back to pixels).  Every axis is grounded before and after, also when
    this is interrupted or ``stop`` is set (:class:`MovesStopped`, within an increment or a
    position's frames); an axis that cannot be grounded (its link lost) is named in the
    :class:`~feeder.drivers.amplifier.AmplifierError` raised.

    Returns the fields of a ``feeder vision calibrate`` report (pixel size, rotation, mirroring,
    O when θ moved, its ``origin_uncertainty_px``, residuals) plus ``offset_v``, ``parts``,
    ``turn_rad`` and ``turn_from``, ``returned_px``, ``slipped``, ``unsteady_px`` (how far the
    image still moved when the wait for a steady one ran out; 0), ``moves_px`` (per axis moved,
    each part's image centre before, at the offset and after: [u, v, u, v, u, v] px) and
    ``warnings`` (sentences).
    """
    if not {"x", "y"} <= set(amplifiers):
        raise InputError("axes", "the plate moves need the x and y axes ([plate] axes)")
    for amp in amplifiers.values():
        amp.ground()
    time.sleep(moves.settle_s)
    images: dict[str, tuple[Points, Points, Points]] = {}
    moving = None  # the axis that may hold an offset
    try:
        for axis in ("x", "y", "theta"):
            if axis not in amplifiers:
                continue
            moving = axis
            before = _image_points(sensor, located_with, moves, stop, axis)
            increment = moves.increment_v
            if axis == "theta":
                reach = RADIUS_MARGIN * max(math.hypot(*located_with.to_plate(u, v)) for u, v in before.mean)
                increment *= min(1.0, moves.lever_arm_m / reach)
            images[axis] = _move(
                amplifiers[axis], axis, increment, sensor, located_with, moves, progress, before, stop
            )
            moving = None
    finally:
        _ground(amplifiers, moving, moves.volts)
    return _fit(images, moves, located_with.pixel_size_m)


def _move(
    amp: Amplifier,
    axis: str,
    increment_v: float,
    sensor: PositionSensor,
    located_with: CameraCalibration,
    moves: OffsetMoves,
    progress: Callable[[str], None],
    before: Points,
    stop: threading.Event | None,
) -> tuple[Points, Points, Points]:
    """One axis up to ``moves.volts`` in ``increment_v`` steps and down in half-steps: the parts'
    image points before, at the offset and after."""

    progress(f"{axis}: offset 0 → {moves.volts:g} V in {increment_v:.3g} V steps")
    amp.ramp_offset(0.0, moves.volts, increment_v, moves.pause_s, stop)
    _check_stop(stop, axis)
    time.sleep(moves.settle_s)
    at = _image_points(sensor, located_with, moves, stop, axis, before)
    progress(f"{axis}: offset {moves.volts:g} → 0 V in {increment_v / 2:.3g} V steps")
    amp.ramp_offset(moves.volts, 0.0, increment_v / 2, moves.pause_s, stop)
    amp.ground()
    _check_stop(stop, axis)
    time.sleep(moves.settle_s)
    return before, at, _image_points(sensor, located_with, moves, stop, axis, at)


def _check_stop(stop: threading.Event | None, axis: str) -> None:
    """:class:`MovesStopped` once ``stop`` is set (on ``axis``)."""
    if stop is not None and stop.is_set():
        raise MovesStopped(f"the plate moves were stopped on axis {axis}; every axis grounded")


def _ground(amplifiers: Mapping[str, Amplifier], moving: str | None, volts: float) -> None:
    """Ground every axis; AmplifierError when one cannot be (its link lost), naming ``moving``,
    the axis that may still hold an offset of up to ``volts``."""
    failed = []
    for name, amp in amplifiers.items():
        try:
            amp.ground()
        except AmplifierError as err:
            failed.append(f"{name} ({err})")
    if failed:
        held = (
            f"axis {moving} may still hold an offset of up to {volts:g} V: ground it by hand (an "
            "ANC300: setm N gnd, then seta N 0)"
            if moving is not None
            else "no axis held an offset"
        )
        raise AmplifierError("could not ground axis " + ", ".join(failed) + f"; {held}")


def _image_points(
    sensor: PositionSensor,
    located_with: CameraCalibration,
    moves: OffsetMoves,
    stop: threading.Event | None,
    axis: str,
    moved_from: Points | None = None,
) -> Points:
    """Every part's centre in the image (parts, 2) px averaged over the last ``moves.frames``
    frames of a steady image, and that mean's standard error (px, per part; from the noise of
    every frame in the window, :func:`_mean_and_error`).

    Frames are read until the image stops moving (:data:`STEADY_FRAMES`; ``moved_from``: the
    points before the move, for :data:`STEADY_FRACTION`), at most ``moves.steady_timeout_s``
    after the first window of them: a fixed settle cannot know a camera's latency (a loaded
    host's, or a lagging simulator's) nor a stack's creep, and frames that still show the plate
    on its way give moves too short (a sample that predates the settle is one of them).
    ``stop`` ends it at the next frame (:func:`_check_stop`, naming ``axis``)."""
    window = max(moves.frames, STEADY_FRAMES)
    half = window // 2
    frames: deque[list[tuple[float, float]]] = deque(maxlen=window)
    started = time.monotonic()
    deadline = math.inf  # from the first full window on
    read = 0
    while True:
        sample = sensor.read(moves.frame_timeout_s)
        read += 1
        _check_stop(stop, axis)
        frames.append([located_with.to_image(x, y) for x, y, _ in sample.poses])
        if len(frames) < window:
            continue
        points = np.array(frames, dtype=float)
        late = points[-half:].mean(axis=0)
        shift = np.hypot(*(late - points[:half].mean(axis=0)).T)
        moved = 0.0 if moved_from is None else np.hypot(*(late - moved_from.mean).T)
        noise = reading_noise(points)
        shift_error = noise * math.sqrt(2 / half)  # of the difference of the halves' means
        allowed = np.maximum(max(STEADY_PX, STEADY_ERRORS * shift_error), STEADY_FRACTION * moved)
        if np.all(shift <= allowed):
            log.debug("steady after %d frames, %.2f s", read, time.monotonic() - started)
            return _mean_and_error(points[-moves.frames :], noise)
        if time.monotonic() > deadline:
            unsteady = float(np.max(shift))
            return _mean_and_error(points[-moves.frames :], noise)._replace(unsteady_px=unsteady)
        if deadline == math.inf:
            deadline = time.monotonic() + moves.steady_timeout_s


def _mean_and_error(points: np.ndarray, noise_px: float) -> Points:
    """The mean of frames' points (frames, parts, 2) px and its standard error (parts,) px from
    one frame's noise ``noise_px`` in a coordinate (:func:`~feeder.reading_noise.reading_noise`
    of the whole steady window: the spread of the few frames averaged, one of them with
    ``--frames 1``, says little)."""
    error = math.sqrt(2 / len(points)) * noise_px  # both coordinates
    return Points(points.mean(axis=0), np.full(points.shape[1], error))


def _fit(
    images: Mapping[str, tuple[Points, Points, Points]], moves: OffsetMoves, located_m: float
) -> dict[str, Any]:
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
    warnings: list[str] = []
    ratio = fit.pixel_size_m / located_m
    if abs(ratio - 1) > SCALE_WARNING:
        warnings.append(
            f"the moves' pixel size is {ratio:.3f} × the {located_m:.4g} m the parts were located with: "
            "check the stack gain (--stack-gain); a camera later than the whole ramp shows no move"
        )
    if "theta" in images:
        centre, move_error = _centre(
            images["theta"], stroke / moves.lever_arm_m, fit.mirrored, fit.residual_px
        )
        report.update(centre, turn_from_gain_rad=stroke / moves.lever_arm_m)
        if report["turn_from"] == "stack gain":
            warnings.append(
                "O rests on --stack-gain and [plate] lever_arm_m (one part: its turn is assumed from "
                "them): an error ε in either puts O ε × the part's distance from O off; two or more "
                "parts measure the turn"
            )
        if report["theta_residual_px"] > 3 * fit.residual_px + 4 * move_error:
            warnings.append(
                f"the parts did not turn as one (θ misfit {report['theta_residual_px']:.3f} px against "
                f"{fit.residual_px:.3f} px in x and y): some slipped; use smaller increments (--increment)"
            )
    returned, slips = 0.0, []
    for axis, (before, at, after) in images.items():  # each axis' return against its own moves
        moved = float(np.min(np.hypot(*(at.mean - before.mean).T)))
        back = float(np.max(np.hypot(*(after.mean - before.mean).T)))
        noise = float(np.max(np.hypot(before.error, after.error)))
        returned = max(returned, back)
        if back > max(moves.slip_fraction * moved, 4 * noise):
            slips.append(f"{back:.3f} px after {axis}'s moves of {moved:.2f} px and more")
    slipped = bool(slips)
    if slipped:
        warnings.append(
            f"the parts came back {', '.join(slips)} (over {moves.slip_fraction:g} of them) from where "
            "they were: they slipped, and the moves are off by a similar amount; use smaller "
            "increments (--increment); a stack that creeps back short of its start reads as this "
            "too (--slip-fraction)"
        )
    unsteady = max(points.unsteady_px for seen in images.values() for points in seen)
    if unsteady:
        warnings.append(
            f"the image still moved {unsteady:.3f} px (between the halves of the last frames) "
            f"after {moves.steady_timeout_s:g} s more of frames: a stack creeping or a camera "
            "lagging; the moves are off by up to a similar amount"
        )
    report.update(
        offset_v=moves.volts,
        plate_move_m=stroke,
        parts=len(images["x"][0].mean),
        returned_px=returned,
        slipped=slipped,
        unsteady_px=unsteady,
        moves_px={axis: np.hstack([p.mean for p in seen]).round(4).tolist() for axis, seen in images.items()},
        warnings=warnings,
    )
    return report


def _centre(
    theta: tuple[Points, Points, Points], assumed_turn: float, mirrored: bool, bias_px: float
) -> tuple[dict[str, Any], float]:
    """O in the image from the θ move, and the move's error (px): the turn measured by the line
    between the parts (two or more) or ``assumed_turn`` (rad, from the stack's gain and lever
    arm), then :func:`rotation_centre`; the error from the frames' and the locator's bias
    ``bias_px`` (which the x and y misfit shows)."""
    before, at, after = theta
    start = 0.5 * (before.mean + after.mean)
    if len(start) >= 2:
        s, a = start - start.mean(axis=0), at.mean - at.mean.mean(axis=0)
        image_turn = math.atan2(float(np.sum(s[:, 0] * a[:, 1] - s[:, 1] * a[:, 0])), float(np.sum(s * a)))
        turn, source = (-image_turn if mirrored else image_turn), "parts"
    else:
        turn, source = assumed_turn, "stack gain"
    ox, oy, residual = rotation_centre(start, at.mean, np.full(len(start), turn), mirrored)
    # a part's move is turn × its distance from O: an error e in the move puts O e / turn off
    move_error = float(np.sqrt(np.mean(at.error**2 + 0.25 * (before.error**2 + after.error**2) + bias_px**2)))
    uncertainty = move_error / (abs(turn) * math.sqrt(len(start)))
    if source == "stack gain":  # and a turn wrong by ε puts O ε × the part's distance off
        uncertainty = math.hypot(uncertainty, GAIN_UNCERTAINTY * math.hypot(*(start[0] - (ox, oy))))
    fields = {
        "origin_x_px": ox,
        "origin_y_px": oy,
        "theta_residual_px": residual,
        "origin_uncertainty_px": uncertainty,
        "turn_rad": turn,
        "turn_from": source,
    }
    return fields, move_error
