"""What the daemon keeps in its state database for its jobs: the learned steps (or, in the plane,
the learned pose response) under the calibration key, and every move from start to end."""

from __future__ import annotations

import functools
import logging
import math
import time
from typing import Any

from feeder.daemon.control_loop import ControlLoop
from feeder.daemon.jobs import Job, JobResult
from feeder.daemon.line_navigator import COARSE, FINE
from feeder.daemon.step_estimator import BACKWARD, FORWARD, StepEstimate
from feeder.daemon.store import Calibration, Store
from feeder.pose import Pose

log = logging.getLogger(__name__)


class MoveRecords:
    """The store as the jobs use it.

    calibration_key: identifies part, support and waveforms: a learned step is only
    reused for the same combination.  pose_control: the plane's navigator, whose
    learned response is kept whole instead of per mode and direction.
    """

    def __init__(self, store: Store, calibration_key: str, pose_control: bool) -> None:
        self.store = store
        self.calibration_key = calibration_key
        self.pose_control = pose_control
        self._loop: ControlLoop | None = None  # the loop the jobs run on (from :meth:`begin`)

    def _key(self, mode_direction: str) -> str:
        return f"{self.calibration_key}/{mode_direction}"

    def restored_estimates(self) -> dict[str, StepEstimate]:
        """The learned steps per ``mode/direction`` kept for this calibration key."""
        out = {}
        for mode in (COARSE, FINE):
            for direction in (FORWARD, BACKWARD):
                name = f"{mode}/{direction}"
                cal = self.store.calibration(self._key(name))
                if cal is None:
                    continue
                kept = StepEstimate(cal.step_m, cal.variance_m2, cal.steps, cal.offset_m,
                                    cal.offset_variance_m2, cal.covariance_m2)  # fmt: skip
                if kept.finite:
                    out[name] = kept
                else:
                    log.warning("the stored step for %s is not a number (%r): learning it again", name, kept)
        return out

    def restored_pose_response(self) -> dict[str, Any] | None:
        """The plane's learned response, only if it was learned with this part and waveforms."""
        kept = self.store.pose_response()
        return kept if kept is not None and kept.get("key") == self.calibration_key else None

    def save_estimates(self, loop: ControlLoop) -> None:
        if self.pose_control:
            self.store.save_pose_response({"key": self.calibration_key, **loop.estimates_json()})
            return
        for cal in self._learned_steps(loop, report=True):
            self.store.save_calibration(cal)

    def _learned_steps(self, loop: ControlLoop, report: bool) -> list[Calibration]:
        """The steps learned so far (those observed at least once), as rows; one that is not a
        number is left out (logged when ``report``)."""
        now = time.time()
        out = []
        for name, est in loop.estimates().items():
            if not est.finite:
                if report:
                    log.error("not stored: the step learned for %s is not a number (%r)", name, est)
            elif est.steps > 0:
                out.append(Calibration(self._key(name), est.step_m, est.variance_m2, est.steps, now,
                                       est.offset_m, est.offset_variance_m2, est.covariance_m2))  # fmt: skip
        return out

    def begin(self, job: Job, loop: ControlLoop) -> None:
        """A move is recorded ``running`` before its first step (a daemon killed mid-move finds it)."""
        self._loop = loop
        if job.kind == "move" and job.target_m is not None:
            reading = loop.reading
            start = None if reading is None or job.target_pose is None else reading[job.part - 1]
            job.record_id = self.store.begin_move(
                job.target_m,
                loop.position_m if start is None else start[0],
                part=job.part if job.target_pose is not None else None,
                target_pose=_asked(job),
                start_pose=start,
            )

    def progress(self, job: Job) -> None:
        """At each burst commanded, in one transaction: the steps and bursts commanded so far and
        the steps (in the plane: the response) learned so far, so that a move or calibration a
        killed daemon leaves behind shows what it had commanded and keeps what it had learned."""
        loop = self._loop
        learned: list[Calibration] = []
        response = None
        if loop is not None and self.pose_control:
            response = {"key": self.calibration_key, **loop.estimates_json()}
        elif loop is not None:
            learned = self._learned_steps(loop, report=False)
        save = functools.partial(self.store.save_progress, job.record_id, steps=job.steps,
                                 bursts=job.bursts, calibrations=learned)  # fmt: skip
        try:
            save(pose_response=response)
        except ValueError as err:  # a response that is not a number: the stored one stays
            log.debug("the response learned so far is not stored: %s", err)
            save()

    def finish(self, job: Job, result: JobResult, loop: ControlLoop) -> None:
        """The learned steps, and the move's end (status, reason, where it ended): logged as INFO
        when it ended as asked (done, stopped), else as a WARNING (a refused command, a lost link,
        a limit: the operator's to read)."""
        level = logging.INFO if result.status in ("done", "stopped") else logging.WARNING
        if result.target_pose is not None:
            out = result.as_dict()
            log.log(
                level,
                "%s of part %d %s: %s (target %s, reached %s, error %s m / %s rad, %d steps in %d bursts)",
                job.kind, result.part, result.status, result.reason, _pose(out["target_pose"]),
                _pose(out["pose"]), _g(result.error_m), _g(result.error_rad), result.steps, result.bursts,
            )  # fmt: skip
        else:
            log.log(
                level,
                "%s %s: %s (target %s m, reached %s m, %d steps in %d bursts)",
                job.kind, result.status, result.reason, result.target_m, result.reached_m, result.steps,
                result.bursts,
            )  # fmt: skip
        self.save_estimates(loop)
        if job.record_id is not None:
            est = result.estimates
            forward, backward = (est.get(f"{COARSE}/{d}", {}).get("step_m") for d in (FORWARD, BACKWARD))
            self.store.finish_move(
                job.record_id,
                status=result.status,
                reason=result.reason,
                reached_m=result.reached_m,
                steps=result.steps,
                bursts=result.bursts,
                step_forward_m=forward,
                step_backward_m=backward,
                steps_estimated=result.steps_estimated,
                reached_pose=(
                    result.reached_on_branch()
                    if result.target_pose is not None and result.reached_pose is not None
                    else None
                ),
                error_m=result.error_m,
                error_rad=result.error_rad,
            )


def _g(value: float | None) -> str:
    return "?" if value is None else f"{value:.6g}"


def _pose(pose: list[float | None] | None) -> str:
    """[x_m, y_m, angle_rad] for the log: "(x, y) m, angle rad" (angle None: any angle)."""
    if pose is None:
        return "?"
    x, y, psi = pose
    return f"({_g(x)}, {_g(y)}) m, " + ("any angle" if psi is None else f"{_g(psi)} rad")


def _asked(job: Job) -> Pose | None:
    """The target the move was given: its angle NaN (stored as null) when any angle will do."""
    if job.target_pose is None or not job.angle_free:
        return job.target_pose
    x, y, _ = job.target_pose
    return (x, y, math.nan)
