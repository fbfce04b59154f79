"""The daemon's plate in the plane (x, y, θ): every axis' waveforms and the pose navigator.

The three stacks are alike, so every axis steps with the one-axis planner's
coarse and fine waveforms (:mod:`feeder.daemon.step_modes`); what a step does
differs: x and y translate every part by the same step, θ turns the plate
about O (the stack's stroke over the lever arm) and moves each part
according to where it sits.  The pose planner (:mod:`feeder.pose_planner`)
is seeded with one period of the planar plant per axis and waveform
(:func:`feeder.pose_response.seed_response`) and learns the rest online.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from feeder.daemon.config import DaemonConfig
from feeder.daemon.jobs import StepMode
from feeder.daemon.pose_navigator import PoseNavigator
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.planar import PlanarPart
from feeder.plant.stack import StackParameters
from feeder.plant.stick_slip import Friction
from feeder.pose_planner import PosePlanner, Travel
from feeder.pose_response import AxisMode, seed_response

log = logging.getLogger(__name__)

SEED_RADII = 8
"""θ response seeded on this many radii from O to the travel's far corner."""


def axis_modes(modes: dict[str, StepMode], axes: tuple[str, ...]) -> dict[str, dict[str, StepMode]]:
    """The waveforms of every axis: the one-axis planner's, on each stack."""
    return {axis: dict(modes) for axis in axes}


def ideal_modes(
    modes: dict[str, StepMode],
    axes: tuple[str, ...],
    limits: AmplifierLimits,
    lever_arm_m: float,
    stack: StackParameters | None = None,
) -> list[AxisMode]:
    """The ideal sawtooth each axis' waveform makes: stroke (m; θ: rad), frequency, and the
    current-limited flyback into the stack's capacitance."""
    stack = stack or StackParameters()
    out = []
    for axis in axes:
        for name, mode in modes.items():
            s = mode.settings
            stroke_m = s.amplitude_v * stack.gain_m_per_v
            flyback_s, _ = limits.current_limited_flyback(s.amplitude_v, s.frequency_hz, stack.capacitance_f)
            stroke = stroke_m / lever_arm_m if axis == "theta" else stroke_m
            out.append(AxisMode(axis, name, stroke, s.frequency_hz, float(flyback_s)))
    return out


def pose_navigator_factory(
    config: DaemonConfig, modes: dict[str, StepMode], static_accel_m_s2: float
) -> Callable[[dict[str, Any] | None], PoseNavigator]:
    """Builds the pose navigator when the daemon starts: the planner seeded from the plant
    (see the module doc) with the gains it learned before (``restored``: what the store kept
    for the same part and waveforms, or None)."""
    loop = config.loop
    part = PlanarPart.from_part(config.part, Friction(static_accel_m_s2))
    travel = Travel((loop.min_position_m, loop.max_position_m), (loop.min_y_m, loop.max_y_m))
    far = max(math.hypot(x, y) for x in travel.x_m for y in travel.y_m)
    radii = tuple(float(r) for r in np.linspace(0.0, far, SEED_RADII))
    ideal = ideal_modes(modes, config.plate.axes, config.amplifier.limits, config.plate.lever_arm_m)

    def build(restored: dict[str, Any] | None) -> PoseNavigator:
        model = seed_response(part, ideal, radii)
        if restored is not None:
            log.info("pose planner: %d learned gains restored", model.restore(restored.get("gains", {})))
        planner = PosePlanner(model, travel, part, loop.tolerance_m, loop.tolerance_rad)
        return PoseNavigator(planner, loop, planner.symmetry_rad)

    return build
