"""A camera whose frames lag more than the policy has seen (no I/O: a fake clock, a toy plate).

On a loaded machine the camera's frames arrive later than the latency the policy learned: the
first frame after the settle time can have been exposed in the burst's tail, the part still
moving.  Measured, it sent the next burst from where the part was passing (the part carried
past its target, off the camera's view on the real plane).  The policy measures only once two
fresh readings agree, also with one frame averaged; and it watches the travel in every reading
while a burst plays, also while its end is being confirmed.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from test_pose_policy import MODES, SETTINGS, STEP_M, StepPlanner, tick

from feeder.daemon.jobs import Command, Completion, Finished, Job, LoopSettings
from feeder.daemon.policy import Policy
from feeder.daemon.pose_navigator import PoseNavigator
from feeder.pose import Pose

DT = 0.01
FREQUENCY_HZ = MODES["fine"].settings.frequency_hz


@dataclass
class LaggingPlane:
    """The toy plate of ``test_pose_policy`` (x and y only), but a burst moves the parts over
    its duration, and the camera shows them ``lag_s`` late.  A drive unlike the model: each step
    ``gain`` × the toy's, a burst ``slow`` × steps / f long, its end confirmed ``confirm_after_s``
    after it was asked (up to the burst grace)."""

    settings: LoopSettings = SETTINGS
    lag_s: float = 0.02
    gain: float = 1.0
    slow: float = 1.0
    confirm_after_s: float = 0.0
    x0_m: float = 100e-6
    now: float = 0.0
    commands: list[Command] = field(default_factory=list)
    motions: list[tuple[float, float, str, float]] = field(default_factory=list)  # start, end, axis, m
    confirming: Command | None = None
    confirm_at_s: float = math.inf

    def __post_init__(self) -> None:
        navigator = PoseNavigator(StepPlanner(), self.settings, math.pi / 2)  # type: ignore[arg-type]
        axis_modes = {a: MODES for a in ("x", "y", "theta")}
        self.policy = Policy(MODES, self.settings, axis_modes=axis_modes, navigator=navigator)

    def truth(self, at_s: float) -> Pose:
        """The part's pose at ``at_s``."""
        x, y = self.x0_m, 0.0
        for start, end, axis, total_m in self.motions:
            shift = min(max((at_s - start) / (end - start), 0.0), 1.0) * total_m
            x, y = (x + shift, y) if axis == "x" else (x, y + shift)
        return (x, y, 0.0)

    def play(self, command: Command) -> None:
        if command.kind == "step":
            end = self.now + self.slow * abs(command.steps) / FREQUENCY_HZ
            self.motions.append((self.now, end, command.axis, self.gain * command.steps * STEP_M))
        elif command.kind == "confirm_end" and self.confirm_after_s > 0:
            self.confirming, self.confirm_at_s = command, self.now + self.confirm_after_s
            return
        elif command.kind == "stop" and self.motions:  # the burst playing ends here
            start, end, axis, total_m = self.motions[-1]
            if self.now < end:
                cut = (self.now - start) / (end - start)
                self.motions[-1] = (start, self.now, axis, cut * total_m)
        self.policy.on_completion(Completion(command, self.now, counter=0))
        if command.kind == "stop" and self.confirming is not None:  # it ends the wait too
            self.policy.on_completion(Completion(self.confirming, self.now, counter=0))
            self.confirming = None

    def run(self, job: Job, limit: int = 3000) -> Finished:
        self.policy.on_sample(self.truth(self.now)[0], self.now, (self.truth(self.now),))
        assert self.policy.submit(job, self.now) is None
        for _ in range(limit):
            self.now += DT
            if self.confirming is not None and self.now >= self.confirm_at_s:
                self.policy.on_completion(Completion(self.confirming, self.now, counter=0))
                self.confirming = None
            seen = self.truth(self.now - self.lag_s)
            self.policy.on_sample(seen[0], self.now, (seen,))
            finished = tick(self.policy, self.now, self.commands, self.play)
            if finished is not None:
                return finished
        raise AssertionError("the job did not finish")

    def steps_sent(self) -> list[int]:
        return [c.steps for c in self.commands if c.kind == "step"]


def _move(plane: LaggingPlane, x_m: float) -> Finished:
    return plane.run(Job("move", pose_target={"x_m": x_m}))


def test_a_frame_from_a_bursts_tail_is_not_measured_with_one_frame_averaged() -> None:
    plane = LaggingPlane(settings=dataclasses.replace(SETTINGS, average_samples=1))
    first = _move(plane, 150e-6)  # the latency is learned at 0.02 s
    assert first.result.status == "done", first.result
    sent = len(plane.steps_sent())
    plane.lag_s = 0.12  # the machine gets loaded: frames lag 6× the latency seen
    second = _move(plane, 300e-6)
    assert second.result.status == "done", second.result
    assert abs(plane.truth(plane.now)[0] - 300e-6) <= SETTINGS.tolerance_m
    assert plane.steps_sent()[sent:] == [150]  # no second burst sent from a frame of the first's tail


def test_the_travel_is_watched_while_a_bursts_end_is_confirmed() -> None:
    """The drive steps 1.5× the model and plays the burst at half the rate, and confirms its end
    0.5 s after it is asked: the part crosses the travel's end in that wait, and the reading
    that shows it stops the output at once."""
    settings = dataclasses.replace(SETTINGS, max_position_m=400e-6)
    plane = LaggingPlane(settings=settings, gain=1.5, slow=2.0, confirm_after_s=0.5)
    finished = _move(plane, 390e-6)  # 290 steps: 435 µm at 1.5×, over 0.58 s; nominal end at 0.29 s
    assert finished.result.status == "limit", finished.result
    assert [c.kind for c in plane.commands].count("stop") == 1
    assert plane.truth(plane.now)[0] < 400e-6 + 40e-6  # stopped within a few frames of the crossing
