"""Waveform designs per plate axis (x, y, θ) for the planar plant, and waveform runs on one axis (DESIGN §9).

API for scripts::

    from feeder.axis_design import design_axis, run_axis_waveform, write_axis_design
    design = design_axis(problem, "theta", pose=(1.5e-3, 0.0, 0.0))   # problem: feeder.design.DesignProblem
    design.turn_rad, design.design.waveform, design.pose_change
    write_axis_design("theta.toml", problem, design)

x and y: a translation of the plate is the 1-D model exactly (DESIGN §9), so an
x or y design is :func:`feeder.design.design_waveform`'s, tagged with its axis
and amplifier channel.

θ: the θ stack turns the plate about O by (stack displacement)/(lever arm).
What a part does depends on its distance r from O: far from O it mostly orbits
O, at O it only turns, and near O it may hardly move within the amplifier's
limits (a dead zone).  The search ranks the amplifier's waveform family on the
1-D plant driven by the plate's tangential motion at r_eff = hypot(r, k) (stack
gain × r_eff / lever arm; k the part's radius of gyration, so a part at O has
a proxy too), then runs the best :data:`PLANAR_CANDIDATES` distinct candidates
on the full planar plant (:class:`feeder.plant.planar_plant.PlanarPlant`:
amplifier, stack, planar stick-slip) at the part's pose and keeps the one that
turns the part furthest per period (max-step) or fastest (max-speed).  Its
prediction — turn Δψ per period (rad), orbit step |Δ(x, y)| (m), their band
over τ's band × the F_k/F_s spread — is the planar plant's.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from feeder.design import (
    GRID_POINTS,
    REFINE_EVALUATIONS,
    TABLE_POINTS,
    VERIFY_PERIODS,
    Design,
    DesignProblem,
    design_waveform,
    margins,
    ranked_search,
    write_design,
)
from feeder.errors import InputError
from feeder.planner import StepPrediction
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.planar import PlanarPart, Pose
from feeder.plant.planar_plant import DEFAULT_LEVER_ARM_M, PlanarPlant
from feeder.plant.plant import DEFAULT_SAMPLE_RATE_HZ
from feeder.plant.stack import StackParameters
from feeder.plant.stick_slip import Friction, kinetic_ratio_band
from feeder.plate_axes import AXES, DEFAULT_AXIS_MAP
from feeder.waveform import FLYBACK_SHAPES, Waveform

log = logging.getLogger(__name__)

PLANAR_CANDIDATES = 5
"""θ: candidates from the 1-D ranking that run on the planar plant."""
PLANAR_PERIODS = 3
"""θ: periods per planar scoring run (after the lead-in rise; the response repeats from the first)."""
THETA_OBJECTIVES = ("max-step", "max-speed")


@dataclass(frozen=True)
class AxisRun:
    """One axis of the planar plant driven for some periods, sampled at the top of each rise.

    poses: (periods + 1, 3) plate-frame poses (m, m, rad), the first after the
    lead-in rise; pose_changes: (periods, 3) their differences.
    """

    poses: np.ndarray
    slip_fraction: float

    @property
    def pose_changes(self) -> np.ndarray:
        return np.diff(self.poses, axis=0)

    @property
    def turns_rad(self) -> np.ndarray:
        return self.pose_changes[:, 2]

    @property
    def steps_m(self) -> np.ndarray:
        """Distance the part's centre moves per period (m)."""
        return np.hypot(self.pose_changes[:, 0], self.pose_changes[:, 1])


def run_axis_waveform(
    part: PlanarPart,
    waveform: Waveform,
    axis: str,
    periods: int,
    amplifier: AmplifierLimits | None = None,
    stack: StackParameters | None = None,
    lever_arm_m: float = DEFAULT_LEVER_ARM_M,
    sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
) -> AxisRun:
    """Drive one channel of a fresh planar plant with ``waveform`` (the others at 0 V).

    Sampled like :func:`feeder.plant.plant.run_waveform` (whole samples per
    period; the first rise is a lead-in); poses are read at the top of each rise.
    """
    if axis not in AXES:
        raise InputError("axis", f"expected one of {', '.join(AXES)}, got {axis!r}")
    if periods < 1:
        raise InputError("periods", f"must be at least 1, got {periods}")
    per = round(sample_rate_hz / waveform.frequency_hz)
    if per < 4:
        raise InputError("sample_rate_hz", "needs at least 4 samples per period")
    plant = PlanarPlant([part], amplifier, stack, per * waveform.frequency_hz, lever_arm_m)
    channel = AXES.index(axis)
    top = math.ceil((1.0 - waveform.command_flyback_s * waveform.frequency_hz) * per - 1e-9) - 1

    def drive(first: int, count: int) -> None:
        command = np.zeros((3, count))
        command[channel] = waveform.voltage_at_phase((np.arange(first, first + count) % per) / per)
        plant.advance(command)

    drive(1, top + 1)
    poses = [plant.poses()[0]]
    for k in range(periods):
        drive(top + 2 + k * per, per)
        poses.append(plant.poses()[0])
    elapsed = plant.contact.elapsed_s
    return AxisRun(np.array(poses), plant.contact.slip_time_s[0] / elapsed if elapsed else 0.0)


@dataclass(frozen=True)
class AxisDesign:
    """A design for one axis: the 1-D design (x, y) or the planar plant's choice (θ).

    For θ, ``design.prediction`` is the orbit step |Δ(x, y)| (m) and its band;
    turn_rad, turn_band_rad: the turn Δψ per period (rad); pose_change:
    (Δx m, Δy m, Δψ rad) per period at ``pose``.
    """

    axis: str
    design: Design
    pose: Pose = (0.0, 0.0, 0.0)
    lever_arm_m: float = DEFAULT_LEVER_ARM_M
    part_shape: str = "rectangle"
    turn_rad: float | None = None
    turn_band_rad: tuple[float, float] | None = None
    pose_change: tuple[float, float, float] | None = None

    @property
    def model(self) -> str:
        return "planar-plant" if self.axis == "theta" else "plant"

    @property
    def radius_m(self) -> float:
        """The part's distance from O (m)."""
        return math.hypot(self.pose[0], self.pose[1])

    def axis_table(self) -> dict[str, Any]:
        """The ``[axis]`` table of the design file (what the pose-control daemon reads)."""
        return {"name": self.axis, "channel": DEFAULT_AXIS_MAP[self.axis], "pose": list(self.pose),
                "radius_m": self.radius_m, "lever_arm_m": self.lever_arm_m,
                "part_shape": self.part_shape, "model": self.model}  # fmt: skip

    def to_json(self) -> dict[str, Any]:
        out = {**self.design.to_json(), "axis": self.axis, "channel": DEFAULT_AXIS_MAP[self.axis],
               "model": self.model, "pose": list(self.pose), "radius_m": self.radius_m}  # fmt: skip
        if self.axis == "theta":
            out.update({"predicted_turn_rad": self.turn_rad,
                        "predicted_turn_band_rad": list(self.turn_band_rad or ()),
                        "predicted_pose_change": list(self.pose_change or ()),
                        "lever_arm_m": self.lever_arm_m})  # fmt: skip
        return out


def design_axis(
    problem: DesignProblem,
    axis: str,
    objective: str = "max-step",
    *,
    pose: Pose = (0.0, 0.0, 0.0),
    lever_arm_m: float = DEFAULT_LEVER_ARM_M,
    part_shape: str = "rectangle",
    shapes: tuple[str, ...] = FLYBACK_SHAPES,
    progress: Callable[[str], None] | None = None,
    **search: Any,
) -> AxisDesign:
    """The best waveform for ``axis`` (x, y: the 1-D design; θ: chosen on the planar plant at ``pose``).

    search: ``grid_points``, ``refine_evaluations``, ``table_points`` as for
    :func:`feeder.design.design_waveform`.
    """
    if axis not in AXES:
        raise InputError("axis", f"expected one of {', '.join(AXES)}, got {axis!r}")
    say = progress or (lambda message: log.info("%s", message))
    if axis != "theta":
        design = design_waveform(problem, objective, shapes=shapes, progress=progress, **search)
        return AxisDesign(axis, design, pose, lever_arm_m, part_shape)
    if objective not in THETA_OBJECTIVES:
        raise InputError("objective", f"theta designs {' or '.join(THETA_OBJECTIVES)}, got {objective!r}")
    a_s, (a_lo, a_hi) = problem.breakaway_accel_m_s2()
    part = PlanarPart.from_part(problem.part, Friction(a_s, problem.kinetic_ratio), pose, part_shape)
    r_eff = math.hypot(math.hypot(pose[0], pose[1]), math.sqrt(part.inertia_kg_m2 / part.mass_kg))
    gain = problem.stack.gain_m_per_v * r_eff / lever_arm_m  # tangential plate motion at r_eff per volt
    proxy = replace(problem, stack=replace(problem.stack, gain_m_per_v=gain))
    say(f"theta: ranking on the 1-D plant at r_eff = {r_eff * 1e3:.3g} mm")
    table_points = search.get("table_points") or TABLE_POINTS.get(problem.amplifier_model)
    ranking, ranked = ranked_search(proxy, objective, table_points, shapes, say,
                                    search.get("grid_points", GRID_POINTS),
                                    search.get("refine_evaluations", REFINE_EVALUATIONS))  # fmt: skip
    candidates: list[Waveform] = []
    for _, wave in ranked:
        if wave not in candidates:
            candidates.append(wave)
        if len(candidates) == PLANAR_CANDIDATES:
            break

    def run(wave: Waveform, accel: float, ratio: float, periods: int = PLANAR_PERIODS) -> AxisRun:
        body = replace(part, friction=Friction(accel, ratio))
        return run_axis_waveform(body, wave, "theta", periods, problem.amplifier, problem.stack, lever_arm_m)

    def value(wave: Waveform, turn: float) -> float:
        return turn * wave.frequency_hz if objective == "max-speed" else turn

    scored = []
    for k, wave in enumerate(candidates, 1):
        turn = float(np.mean(run(wave, a_s, problem.kinetic_ratio).turns_rad))
        say(f"planar {k}/{len(candidates)}: {wave.flyback_shape}, {wave.frequency_hz:.5g} Hz, "
            f"{wave.amplitude_vpp:.5g} Vpp → {turn * 1e3:.4g} mrad/period")  # fmt: skip
        scored.append((value(wave, turn), wave))
    best_value, wave = max(scored, key=lambda c: c[0])
    if best_value <= 0:
        raise InputError("--pose", f"no waveform within the amplifier's limits turns the part at {pose}")
    say(f"theta: checking over {VERIFY_PERIODS} periods and the band")
    check = run(wave, a_s, problem.kinetic_ratio, VERIFY_PERIODS)
    r_lo, r_hi = kinetic_ratio_band(problem.kinetic_ratio)
    ends = [run(wave, a_hi, r_hi), run(wave, a_lo, r_lo)]
    turn, step = float(np.mean(check.turns_rad)), float(np.mean(check.steps_m))
    turns = [turn, *(float(np.mean(e.turns_rad)) for e in ends)]
    steps = [step, *(float(np.mean(e.steps_m)) for e in ends)]
    change = np.mean(check.pose_changes, axis=0)
    design = Design(
        objective=objective,
        waveform=wave,
        prediction=StepPrediction(step, (min(steps), max(steps))),
        margins=margins(wave, proxy),
        verified_step_mean_m=step,
        evaluations=ranking.evaluations + len(candidates) + 3,
        table_points=table_points,
    )
    return AxisDesign("theta", design, pose, lever_arm_m, part_shape, turn, (min(turns), max(turns)),
                      (float(change[0]), float(change[1]), float(change[2])))  # fmt: skip


def write_axis_design(path: Path | str, problem: DesignProblem, axis_design: AxisDesign,
                      written_by: str = "feeder.axis_design") -> None:  # fmt: skip
    """Write the design file: ``[waveform]``, ``[amplifier]``, ``[stack]``, ``[prediction]``,
    ``[design]``, ``[margins]`` and ``[axis]`` (θ: the prediction is the planar plant's)."""
    d = axis_design.design
    tables = {**d.tables(), "axis": axis_design.axis_table()}
    if axis_design.axis == "theta":
        prediction = problem.prediction_table(d.prediction, written_by)
        prediction.update({"model": "planar-plant", "predicted_turn_rad": axis_design.turn_rad,
                           "predicted_turn_band_rad": list(axis_design.turn_band_rad or ()),
                           "predicted_pose_change": list(axis_design.pose_change or ())})  # fmt: skip
        tables["prediction"] = prediction
    write_design(path, problem, d.waveform, d.prediction, tables, written_by)
