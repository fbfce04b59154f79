"""The daemon's plate in the plane (x, y, θ): every axis' waveforms and the pose navigator.

The three stacks are alike: x and y step with the one-axis planner's coarse
and fine waveforms (:mod:`feeder.daemon.step_modes`), θ with the planner's at
:data:`THETA_FREQUENCY_HZ` (and, with several parts on a CANopen drive, anchoring ones besides:
:func:`plan_theta_modes`).  What a step does differs: x and y translate every
part by the same step, θ turns the plate about O (the stack's stroke over the
lever arm) and moves each part according to where it sits.  The pose planner (:mod:`feeder.pose_planner`)
is seeded with one period of the planar plant per axis and waveform
(:func:`feeder.pose_response.seed_response`) and learns the rest online.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from feeder.daemon.config import DaemonConfig
from feeder.daemon.jobs import StepMode
from feeder.daemon.pose_navigator import PoseNavigator
from feeder.daemon.step_modes import plan_step_modes
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.planar import PlanarPart
from feeder.plant.stack import StackParameters
from feeder.plant.stick_slip import Friction
from feeder.pose_planner import PosePlanner
from feeder.pose_response import ANCHOR_MODES, MODES, AxisMode, seed_response
from feeder.surface.parameters import SurfaceParameters
from feeder.travel import Travel

log = logging.getLogger(__name__)

SEED_RADII = 8
"""θ response seeded on this many radii from O to the travel's far corner."""
DONE_MARGIN = 0.1
"""A pose move is done when the camera reads the part within (1 − this) × each tolerance: the
camera's reading lies off the truth by up to ~0.1 µm and ~5e-4 rad (MJPEG, the part's edges on
the pixel grid; tests/test_plane_hil.py), so "done" at the tolerance itself left the truth up to
that far beyond it (the demo's truth check failed once in CI)."""
THETA_FREQUENCY_HZ = 1000.0
"""θ steps at 1 kHz (137 V on the ANC300's rating): three times the stroke per step of the
translations' fastest waveform, so a turn takes fewer steps; each step of a turning part is
also what costs a simulated plant most."""
ANCHOR_THETA_FREQUENCY_HZ = 100.0
"""With several parts on a drive that plays a designed flyback (CANopen), θ also has waveforms at
100 Hz with a smooth one (:func:`anchor_modes`): parts near O stay held while the others orbit."""
ANCHOR_BREAK_RADIUS_M = 1.2e-3
"""... designed so that the ideal plate breaks parts loose only beyond this radius from O; the
stack's ringing (ζ = 0.1) adds to the flyback's acceleration, and on the simulated plant parts
within ~0.7 mm stay put (docs/pose-control.md)."""


def anchor_flyback_s(stroke_rad: float, static_accel_m_s2: float, radius_m: float) -> float:
    """The half-cosine flyback (s) of a θ stroke (rad) whose peak tangential acceleration at
    ``radius_m``, (π²/2)·Θ·r/t_f², is the breakaway acceleration: parts nearer O stay held."""
    return math.pi * math.sqrt(stroke_rad * radius_m / (2 * static_accel_m_s2))


def anchor_modes(
    theta_modes: dict[str, StepMode],
    static_accel_m_s2: float,
    lever_arm_m: float,
    stack: StackParameters,
) -> dict[str, StepMode]:
    """θ's waveforms with a dead zone, named :data:`~feeder.pose_response.ANCHOR_MODES` (coarse
    first): each of ``theta_modes`` (coarse, fine) with a half-cosine flyback
    (:func:`anchor_flyback_s` at :data:`ANCHOR_BREAK_RADIUS_M`)."""
    gain = stack.gain_m_per_v
    out = {}
    for name, anchor in zip(MODES, ANCHOR_MODES, strict=True):
        mode = theta_modes[name]
        s = mode.settings
        flyback_s = anchor_flyback_s(
            s.amplitude_v * gain / lever_arm_m, static_accel_m_s2, ANCHOR_BREAK_RADIUS_M
        )
        smooth = dataclasses.replace(s, flyback_shape="half-cosine", flyback_s=flyback_s)
        out[anchor] = dataclasses.replace(mode, name=anchor, settings=smooth)
    return out


def plan_theta_modes(
    config: DaemonConfig, surface: SurfaceParameters, static_accel_m_s2: float
) -> dict[str, StepMode]:
    """θ's waveforms: coarse and fine, the one-axis planner's at :data:`THETA_FREQUENCY_HZ` (they
    turn a part anywhere, O included); with several parts on a CANopen drive (which plays the
    flyback as designed) also :func:`anchor_modes` at :data:`ANCHOR_THETA_FREQUENCY_HZ`, which
    the pair strategy orbits with while coarse and fine turn single parts.  An ANC300 plays
    256-point 8-bit tables: their flyback's corners break parts loose even at 0.5 mm from O
    (they turn 0.01–0.03 mrad per step there), so no part could be held while another orbits."""
    modes = plan_step_modes(config, surface, THETA_FREQUENCY_HZ)
    if len(config.plate.parts) > 1 and config.amplifier.transport == "can":
        slow = plan_step_modes(config, surface, ANCHOR_THETA_FREQUENCY_HZ)
        modes |= anchor_modes(slow, static_accel_m_s2, config.plate.lever_arm_m, config.planning_stack)
    return modes


def theta_key(theta_modes: dict[str, StepMode]) -> str:
    """What θ's learned response belongs to (appended to the calibration key)."""
    return "theta/" + "/".join(
        f"{m.settings.frequency_hz:g}Hz/{m.settings.amplitude_v:.3f}V/{m.settings.flyback_shape}"
        f"/{m.settings.flyback_s or 0:.3e}s"
        for m in theta_modes.values()
    )


def axis_modes(
    modes: dict[str, StepMode], theta_modes: dict[str, StepMode], axes: tuple[str, ...]
) -> dict[str, dict[str, StepMode]]:
    """The waveforms of every axis: x and y the one-axis planner's, θ its own (``theta_modes``,
    :func:`plan_theta_modes`)."""
    return {axis: dict(theta_modes if axis == "theta" else modes) for axis in axes}


def ideal_modes(
    modes: dict[str, dict[str, StepMode]],
    limits: AmplifierLimits,
    lever_arm_m: float,
    stack: StackParameters,
) -> list[AxisMode]:
    """The ideal sawtooth each axis' waveform makes: stroke (m; θ: rad), frequency, and the
    current-limited flyback into the stack's capacitance."""
    out = []
    for axis, axis_modes in modes.items():
        for name, mode in axis_modes.items():
            s = mode.settings
            stroke_m = s.amplitude_v * stack.gain_m_per_v
            stroke = stroke_m / lever_arm_m if axis == "theta" else stroke_m
            if s.flyback_s is not None and s.flyback_shape != "current-limited":
                out.append(AxisMode(axis, name, stroke, s.frequency_hz, s.flyback_s, s.flyback_shape))
                continue
            flyback_s, _ = limits.current_limited_flyback(s.amplitude_v, s.frequency_hz, stack.capacitance_f)
            out.append(AxisMode(axis, name, stroke, s.frequency_hz, float(flyback_s)))
    return out


def pose_navigator_factory(
    config: DaemonConfig, modes: dict[str, dict[str, StepMode]], static_accel_m_s2: float
) -> Callable[[dict[str, Any] | None], PoseNavigator]:
    """Builds the pose navigator when the daemon starts: the planner seeded from the plant
    (see the module doc) with the gains it learned before (``restored``: what the store kept
    for the same part and waveforms, or None)."""
    loop = config.loop
    part = PlanarPart.from_part(config.part, Friction(static_accel_m_s2))
    travel = Travel((loop.min_position_m, loop.max_position_m), (loop.min_y_m, loop.max_y_m))
    far = max(math.hypot(x, y) for x in travel.x_m for y in travel.y_m)
    radii = tuple(float(r) for r in np.linspace(0.0, far, SEED_RADII))
    ideal = ideal_modes(modes, config.amplifier.limits, config.plate.lever_arm_m, config.planning_stack)

    def build(restored: dict[str, Any] | None) -> PoseNavigator:
        model = seed_response(part, ideal, radii)
        if restored is not None:
            log.info("pose planner: %d learned gains restored", model.restore(restored.get("gains", {})))
        aim = 1 - DONE_MARGIN
        planner = PosePlanner(model, travel, part, aim * loop.tolerance_m, aim * loop.tolerance_rad)
        return PoseNavigator(planner, loop, planner.symmetry_rad)

    return build
