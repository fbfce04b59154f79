"""The closed loop's decisions in the plane: which axis (x, y, θ) to step to bring a part to a pose.

:class:`PoseNavigator` adapts the pose planner (:mod:`feeder.pose_planner`,
pure: poses in, an axis burst out) to the policy's navigator interface
(:class:`~feeder.daemon.navigator.Navigator`).  Targets given in part (any of
``x_m``, ``y_m``, ``angle_rad``) keep the part's current value for the rest;
a one-axis move (``target_m``/``by_m``) is a move of part 1's x.  Parts
brought to a target stay *held* there: a later move of another part keeps
them at their targets, or is refused when the planner cannot do both.  A hold
keeps what the move asked for: the position, and the angle only when one was
given (else NaN, any angle); :meth:`release` lets parts go (``feeder release``),
and a move of a held part replaces its hold once done.  Holds live in memory: a
restarted daemon holds nothing.  A part outside the travel (placed there by hand, or carried
there) blocks no move: the move stops only when a part goes out of it, or one that was outside
goes further out (:meth:`PoseNavigator.outside`); the planner cuts every burst before that
(:meth:`~feeder.travel.Travel.keeps`).
"""

from __future__ import annotations

import logging
import math
from typing import Any

from feeder.daemon.jobs import VISIBLE_BANDS, Burst, Job, LoopSettings, Reading
from feeder.daemon.navigator import not_on_plate
from feeder.daemon.request_fields import beyond_one_turn
from feeder.daemon.step_estimator import BACKWARD, FORWARD, StepEstimate
from feeder.plate_axes import AXES
from feeder.pose import Pose, pose_error
from feeder.pose_burst import AxisBurst, Finish
from feeder.pose_planner import PosePlanner
from feeder.travel import Travel

log = logging.getLogger(__name__)


class PoseNavigator:
    """Decisions over the plate's x, y and θ axes (see the module doc).

    planner: the pose planner (travel, tolerances, the parts and the learned response);
    settings: the loop's tuning (travel and tolerances for the checks done here);
    symmetry_rad: the part's angular symmetry (π rectangle, π/2 square, 0 disc).
    """

    axes: tuple[str, ...] = AXES

    def __init__(self, planner: PosePlanner, settings: LoopSettings, symmetry_rad: float) -> None:
        self.planner = planner
        self.settings = settings
        self.symmetry_rad = symmetry_rad
        self.held: dict[int, Pose] = {}
        self.travel = Travel(
            (settings.min_position_m, settings.max_position_m), (settings.min_y_m, settings.max_y_m)
        )
        self._start: Reading = ()  # the parts where the running move started (every plane job is prepared)
        self._theta_rests_at_zero = False  # θ's last burst since the start went forward (:meth:`next_burst`)
        self._zeroing = False  # the last burst decided is the one step that takes θ to 0 V

    # -- the job's target --------------------------------------------------------------

    def prepare(self, job: Job, reading: Reading | None) -> str | None:
        if reading is None:
            return "position uncertain: no camera reading yet"
        missing = not_on_plate(job.part, reading)
        if missing is not None:
            return missing
        now = reading[job.part - 1]
        # what the move does not give stays: where the part is, or where a held part is held
        # (its reading lies within the tolerance of that: a θ jog, or a jog in y, took the
        # reading's x and y for the new hold, and holds drifted jog by jog), its angle too when
        # the hold has one and the pair strategy keeps it (an x jog dropped it)
        held = self.held.get(job.part)
        x, y = (held or now)[:2]
        others = [p for p in self.held if p != job.part]
        kept = held[2] if held is not None and all(job.part < p for p in others) else math.nan
        spec = dict(job.pose_target or {})
        if job.by_m is not None:
            spec["x_m"] = x + job.by_m
        elif job.target_m is not None:
            spec["x_m"] = job.target_m
        if not math.isnan(kept):
            spec.setdefault("angle_rad", kept)
        angle = spec.get("angle_rad", now[2])
        if math.isfinite(angle) and (wrong := beyond_one_turn(angle)) is not None:
            return wrong  # a job from the policy's callers; a request's field was checked already
        target = (spec.get("x_m", x), spec.get("y_m", y), math.remainder(angle, 2 * math.pi))
        if not all(math.isfinite(v) for v in target):
            return "the target pose must be finite"
        s = self.settings
        if not self.travel.contains(target[0], target[1]):
            return (
                f"target ({target[0]:.6g}, {target[1]:.6g}) m is outside the travel "
                f"x [{s.min_position_m:.6g}, {s.max_position_m:.6g}] m, "
                f"y [{s.min_y_m:.6g}, {s.max_y_m:.6g}] m"
            )
        # beside a held part the angle, when not asked for, is left free (the pair strategy
        # turns the moved part as it orbits it about O)
        job.angle_free = "angle_rad" not in spec and bool(others)
        refused = self.planner.check(self._targets(job, target), list(reading))
        if refused is not None:
            if others:
                names = ", ".join(str(p) for p in sorted(others))
                return f"{refused} (held: part {names}; `feeder release` lets held parts go)"
            return refused
        self.held.pop(job.part, None)  # re-placed: held again where this move ends done
        job.target_pose = target
        job.target_m = target[0]
        job.angle_asked = "angle_rad" in spec
        self._start = reading
        return None

    def _targets(self, job: Job, target: Pose) -> dict[int, Pose]:
        """The job's target (angle NaN when free) and every other part's held pose."""
        targets = {p: pose for p, pose in self.held.items() if p != job.part}
        targets[job.part] = (target[0], target[1], math.nan) if job.angle_free else target
        return targets

    def outside(self, reading: Reading) -> str | None:
        """Why the running move must stop: a part went further outside the travel than where the
        move started it, by more than the settle band (the readings' noise, and the plate's rest
        moving on an enable); None.  A part outside the travel at the start may stay there, as a
        move that brings it back or leaves it be does (it blocked every move until 2026-11-27);
        one the start lacks must be within."""
        for i, now in enumerate(reading):
            start = self._start[i] if i < len(self._start) else None
            if start is None and self.travel.contains(now[0], now[1]):
                continue
            if start is not None and self.travel.keeps(start, now, self.settings.settle_band_m):
                continue
            reason = f"part {i + 1} at ({now[0]:.6g}, {now[1]:.6g}) m is outside the travel limits"
            if start is not None and any(self.travel.beyond(start[0], start[1])):
                reason += f", further out than at the move's start, ({start[0]:.6g}, {start[1]:.6g}) m"
            return reason
        return None

    def settled(self, recent: list[Reading]) -> bool:
        """Every part's readings agree within the tolerances (or six sensor sigmas)."""
        s = self.settings
        band_m = s.settle_band_m
        first = recent[0]
        for reading in recent[1:]:
            for a, b in zip(first, reading, strict=False):
                distance, angle = pose_error(a, b, 2 * math.pi)
                if distance > band_m or angle > s.tolerance_rad:
                    return False
        return True

    # -- bursts -----------------------------------------------------------------------

    def learn(self, burst: Burst, learnable: bool, before: Reading, after: Reading) -> bool:
        """Teach the planner what the burst did; True when no part moved beyond the noise."""
        if burst.axis == "theta":
            # the step to 0 V is not learned from: the plate's turn to 0 V is most of what it did
            learnable = learnable and not self._zeroing
            self._theta_rests_at_zero, self._zeroing = burst.direction == FORWARD, False
        if learnable:
            self.planner.learn(_axis_burst(burst), list(before), list(after))
        noise_m = max(3 * self.settings.sensor_noise_m, 0.1 * self.settings.tolerance_m)
        changes = [pose_error(a, b, 2 * math.pi) for a, b in zip(before, after, strict=False)]
        return all(distance <= noise_m and angle <= 1e-4 for distance, angle in changes)

    def expects_motion(self, burst: Burst, reading: Reading) -> bool:
        """Some part should move or turn by over :data:`VISIBLE_BANDS` settle bands (:meth:`settled`)."""
        s = self.settings
        band_m, band_rad = VISIBLE_BANDS * s.settle_band_m, VISIBLE_BANDS * s.tolerance_rad
        effects = self.planner.burst_effect(_axis_burst(burst), list(reading))
        return any(moved > band_m or turned > band_rad for moved, turned in effects)

    def next_burst(self, job: Job, reading: Reading) -> Burst | tuple[str, str]:
        assert job.target_pose is not None
        targets = self._targets(job, job.target_pose)
        self._zeroing = False
        nxt = self.planner.next_burst(list(reading), targets)
        log.debug("at %s for %s: %s", reading, job.target_pose, nxt)
        if isinstance(nxt, Finish):
            if nxt.status == "unreachable" and self._within_tolerance(reading, targets):
                # the planner aims within DONE_MARGIN of the tolerance: a part the re-audit left
                # 0.90-0.96 µm from a target on the travel's edge (tolerance 1 µm) ended unreachable
                nxt = Finish("done", f"every part within tolerance (closer is out of reach: {nxt.reason})")
            if nxt.status == "done" and len(targets) > 1 and not self._theta_rests_at_zero:
                settle = self._theta_to_zero()
                if settle is not None:
                    return settle
            return (nxt.status, nxt.reason)
        return Burst(nxt.mode, FORWARD if nxt.direction > 0 else BACKWARD, nxt.steps, nxt.axis, nxt.path)

    def _theta_to_zero(self) -> Burst | None:
        """One forward step of θ's finest orbit mode, which leaves its output at 0 V, where the
        done check's ground leaves the plate (None: θ has no orbit mode).  Parts placed together
        are done only with θ there: after backward steps the output rests at the top of its
        table, and grounding it turns the plate about O with every part stuck to it, which turns
        the pair and which no translation undoes (a CANopen pair 1.1 mm apart read 2.3–4.3 µm off
        after each of its 4 grounds).  Once at 0 V the planner corrects that turn with forward
        orbits.  The pair planner's backward orbits aim past their end
        (:data:`~feeder.pose_pair.PAST`), so this step is rarely needed: a θ unknown since the
        start (a former daemon's) counts as not at 0 V."""
        modes = self.planner.model.orbit_modes()
        if not modes:
            return None
        log.info("the parts are placed with θ resting after backward steps: one forward step first")
        self._zeroing = True
        return Burst(modes[-1], FORWARD, 1, "theta")

    def _within_tolerance(self, reading: Reading, targets: dict[int, Pose]) -> bool:
        """Every part with a target (or a held pose) is within the move's tolerance of it."""
        for part, target in targets.items():
            if part > len(reading):
                return False
            distance, angle = pose_error(reading[part - 1], target, self.symmetry_rad)
            if distance > self.settings.tolerance_m or angle > self.settings.tolerance_rad:  # NaN: any angle
                return False
        return True

    def reached(self, job: Job, reading: Reading) -> None:
        """The job is done at ``reading``: its part is held at its target from now on (its
        angle only when the move asked for one)."""
        assert job.target_pose is not None
        x, y, psi = job.target_pose
        self.held[job.part] = (x, y, psi if job.angle_asked else math.nan)

    def release(self, part: int | None = None) -> list[int]:
        """Let ``part`` (None: every part) go: later moves no longer keep it; the ids released."""
        released = sorted(self.held) if part is None else [part] if part in self.held else []
        for p in released:
            del self.held[p]
        return released

    def holds(self) -> list[dict[str, Any]]:
        """Each held part and its held pose [x_m, y_m, angle_rad or None: any angle]."""
        return [
            {"part": p, "pose": [x, y, None if math.isnan(psi) else psi]}
            for p, (x, y, psi) in sorted(self.held.items())
        ]

    # -- what it learned ---------------------------------------------------------------

    def axis_steps(self, pose: Pose | None) -> dict[str, dict[str, float]]:
        """Each axis' learned step forward and back (a jog of N steps moves by N of them): x and
        y the coarse step in m (``step_m``, ``step_back_m``, sizes); θ the turn (rad) of a part at
        ``pose`` by one +θ step (``step_rad``) and by one −θ step, sign flipped
        (``step_back_rad``), where the planner turns it (left out: no θ mode turns it anywhere;
        :meth:`~feeder.pose_turns.TurnPlanner.turn_per_step`)."""
        model = self.planner.model
        out: dict[str, dict[str, float]] = {
            axis: {
                "step_m": model.step_m(axis, 1, "coarse")[0],
                "step_back_m": model.step_m(axis, -1, "coarse")[0],
            }
            for axis in ("x", "y")
            if axis in self.axes
        }
        if "theta" in self.axes and pose is not None:
            out["theta"] = {}
            for key, direction in (("step_rad", 1), ("step_back_rad", -1)):
                turn = self.planner.turns.turn_per_step(direction, pose)
                if turn is not None:
                    out["theta"][key] = direction * turn
        return out

    def estimates(self) -> dict[str, StepEstimate]:
        return {}

    def estimates_json(self) -> dict[str, Any]:
        return self.planner.estimates_json()


def _axis_burst(burst: Burst) -> AxisBurst:
    return AxisBurst(burst.axis, 1 if burst.direction == FORWARD else -1, burst.steps, burst.mode)
