"""θ's two families of waveforms with several parts on a CANopen drive (docs/pose-control.md, two
parts): the 1 kHz ones turn a single part, the anchoring ones orbit a pair; one part, or an
ANC300, plans θ as before."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from feeder.cli.demo_plane import config_for
from feeder.contact.breakaway import contact
from feeder.daemon.config import DaemonConfig
from feeder.daemon.jobs import StepMode
from feeder.daemon.plane import (
    ANCHOR_THETA_FREQUENCY_HZ,
    THETA_FREQUENCY_HZ,
    axis_modes,
    plan_theta_modes,
    pose_navigator_factory,
)
from feeder.daemon.step_modes import plan_step_modes
from feeder.parts import Part
from feeder.pose_pair import anchor_radius_m
from feeder.pose_planner import AxisBurst, PosePlanner
from feeder.pose_response import ANCHOR_MODES, MODES
from feeder.surface.parameters import DEFAULT_SURFACE

PART = Part.parse("300x300x50")
PARTS = ((-0.9e-3, 0.1e-3, 0.1), (0.9e-3, -0.1e-3, 0.3))


def world(transport: str, parts: tuple[tuple[float, float, float], ...], tmp_path: Path) -> DaemonConfig:
    config = config_for(PART, transport, tmp_path)
    return dataclasses.replace(config, plate=dataclasses.replace(config.plate, parts=parts))


def static_accel(config: DaemonConfig) -> float:
    return contact(config.part, config.support, DEFAULT_SURFACE, config.tau_pa).breakaway_accel_m_s2


def planner(config: DaemonConfig, theta: dict[str, StepMode]) -> PosePlanner:
    """The daemon's pose planner (as :func:`~feeder.daemon.runner.start_daemon` builds it), θ: ``theta``."""
    every = axis_modes(plan_step_modes(config, DEFAULT_SURFACE), theta, config.plate.axes)
    return pose_navigator_factory(config, every, static_accel(config))(None).planner


def test_one_part_or_an_anc300_keep_the_1_khz_modes_and_canopen_adds_the_anchoring_ones(
    tmp_path: Path,
) -> None:
    for config in (world("can", PARTS[:1], tmp_path), world("serial", PARTS, tmp_path)):
        turning = plan_step_modes(config, DEFAULT_SURFACE, THETA_FREQUENCY_HZ)
        assert plan_theta_modes(config, DEFAULT_SURFACE, static_accel(config)) == turning
    can = world("can", PARTS, tmp_path)
    both = plan_theta_modes(can, DEFAULT_SURFACE, static_accel(can))
    assert list(both) == [*MODES, *ANCHOR_MODES]
    assert {k: both[k] for k in MODES} == plan_step_modes(can, DEFAULT_SURFACE, THETA_FREQUENCY_HZ)
    for name in ANCHOR_MODES:
        s = both[name].settings
        assert both[name].name == name and s.frequency_hz == ANCHOR_THETA_FREQUENCY_HZ
        assert s.flyback_shape == "half-cosine" and s.flyback_s is not None


def test_on_canopen_a_part_among_others_turns_and_a_pair_orbits_as_with_the_anchoring_modes_alone(
    tmp_path: Path,
) -> None:
    """The old planning (θ = the anchoring waveforms only) refused every turn with two parts
    ("no θ mode turns the part anywhere within the travel"); its pairs are planned alike."""
    config = world("can", PARTS, tmp_path)
    both = plan_theta_modes(config, DEFAULT_SURFACE, static_accel(config))
    new = planner(config, both)
    old = planner(
        config, {m: dataclasses.replace(both[a], name=m) for m, a in zip(MODES, ANCHOR_MODES, strict=True)}
    )
    turn = {2: (*PARTS[1][:2], PARTS[1][2] + math.radians(20))}
    assert old.check(turn, list(PARTS)) == "no θ mode turns the part anywhere within the travel"
    assert new.check(turn, list(PARTS)) is None
    first = new.next_burst(list(PARTS), turn)
    assert isinstance(first, AxisBurst) and first.axis == "theta" and first.mode in MODES

    assert anchor_radius_m(new) == anchor_radius_m(old) > 0.4e-3
    held = [(0.0, 0.0, 0.1), (1.8e-3, 0.4e-3, 0.3)]
    pair = {1: held[0], 2: (1.4e-3, 1.1e-3, math.nan)}
    assert new.check(pair, held) is None and old.check(pair, held) is None
    orbit = new.theta_burst(held, 1, 0.3, anchored=(0,), quantity="orbit")
    before = old.theta_burst(held, 1, 0.3, anchored=(0,), quantity="orbit")
    assert isinstance(orbit, AxisBurst) and isinstance(before, AxisBurst)
    assert orbit == dataclasses.replace(before, mode=ANCHOR_MODES[MODES.index(before.mode)])
