"""The daemon's calibration job without I/O: its bursts, the fine steps, the room on the travel."""

from __future__ import annotations

import pytest

from feeder.daemon.calibration import ROOM_AHEAD, calibration_bursts, calibration_room, fine_steps_for
from feeder.daemon.jobs import LoopSettings, StepMode
from feeder.daemon.line_navigator import COARSE, FINE
from feeder.daemon.step_estimator import BACKWARD, FORWARD, StepEstimate
from feeder.drivers.amplifier import DriveSettings

TRAVEL = LoopSettings(min_position_m=0.0, max_position_m=10e-3)


def test_the_bursts_go_out_and_back_by_the_same_steps() -> None:
    bursts = calibration_bursts(20, 8)
    for mode, total in ((COARSE, 20), (FINE, 8)):
        for direction in (FORWARD, BACKWARD):
            steps = [b.steps for b in bursts if b.mode == mode and b.direction == direction]
            assert steps == [1, total // 4, total - total // 4]


def test_fine_steps_cover_a_quarter_of_the_coarse_way() -> None:
    settings = DriveSettings(frequency_hz=100.0, amplitude_v=200.0)
    modes = {COARSE: StepMode(COARSE, settings, 3.3e-6, (3e-6, 3.6e-6)),
             FINE: StepMode(FINE, settings, 0.5e-6, (0.4e-6, 0.6e-6))}  # fmt: skip
    assert fine_steps_for(20, modes) == round(20 * 3.3 / 0.5 / 4)  # 33
    assert fine_steps_for(1, modes) == 2  # at least two: one burst short, one long


def test_the_room_is_set_by_the_nearer_limit_at_a_pessimistic_step() -> None:
    learned = StepEstimate(10e-6, (1e-6) ** 2)  # pessimistic: 12 µm
    # ahead 8 mm / 1.25 = 6.4 mm, behind 2 mm / 0.25 = 8 mm: 6.4 mm / 12 µm = 533.3 → 533 − 1
    assert calibration_room(2e-3, TRAVEL, learned, 5e-6) == 532
    # behind 1 mm / 0.25 = 4 mm is nearer now: 4 mm / 12 µm = 333.3 → 333 − 1
    assert calibration_room(1e-3, TRAVEL, learned, 5e-6) == 332
    # the predicted band's top when it is above the learned step's: 6.4 mm / 20 µm = 320 → 319
    assert calibration_room(2e-3, TRAVEL, learned, 20e-6) == 319


@pytest.mark.parametrize("position_m", [10e-3 - 2 * ROOM_AHEAD * 12e-6, 1e-6])
def test_no_room_near_either_limit_is_a_reason_naming_both_distances(position_m: float) -> None:
    reason = calibration_room(position_m, TRAVEL, StepEstimate(10e-6, (1e-6) ** 2), 5e-6)
    assert isinstance(reason, str)
    assert reason.startswith("no room to calibrate") and "move it inwards" in reason
    assert f"{TRAVEL.max_position_m - position_m:.3g} m from the upper" in reason
