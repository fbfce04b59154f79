"""Every burst the pose planner sends keeps every part within the travel with the response at the
worst it plausibly is; one burst (a misreading) neither collapses the learned spread nor lifts
the probe (models built by hand, linear worlds: fast)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feeder.parts import Part
from feeder.plant.planar import PlanarPart
from feeder.plant.stick_slip import Friction
from feeder.pose import Pose
from feeder.pose_burst import AxisBurst, Finish
from feeder.pose_gain import SEED_STD
from feeder.pose_planner import PosePlanner
from feeder.pose_response import ResponseModel, TurnTable
from feeder.travel import Travel

SQUARE = PlanarPart.from_part(Part.parse("300x300x50"), Friction(105.25, 0.8))
TRAVEL = Travel((-2.4e-3, 2.4e-3), (-2.4e-3, 2.4e-3))
"""The embedded plane's (``feeder daemon``: its camera sees ±2.765 mm)."""
SEEDS = {("x", "coarse"): 3.47e-6, ("x", "fine"): 0.35e-6, ("y", "coarse"): 3.47e-6, ("y", "fine"): 0.35e-6}
TRUE_GAIN = 0.72
"""The audit's plant: the coarse x step ~2.5 µm, 0.72 of its seed."""
MISREAD = 0.30 / TRUE_GAIN
"""The audit's misreading: a frame in the burst's tail showed 0.42 of the way (x−/coarse learned
0.30 ± 0.03 from it)."""
NAN = math.nan


class Plate:
    """x and y steps of ``gain`` × the seed, exactly (every part alike)."""

    def __init__(self, poses: list[Pose], gain: float = TRUE_GAIN) -> None:
        self.poses = list(poses)
        self.gain = gain
        self.path: list[list[Pose]] = []

    def burst(self, b: AxisBurst) -> list[Pose]:
        d = b.direction * b.steps * self.gain * SEEDS[(b.axis, b.mode)]
        shift = (d, 0.0) if b.axis == "x" else (0.0, d)
        self.poses = [(x + shift[0], y + shift[1], psi) for x, y, psi in self.poses]
        self.path.append(self.poses)
        return self.poses


def misread(before: list[Pose], after: list[Pose], seen: float = MISREAD) -> list[Pose]:
    """The camera's reading of a burst from ``before`` to ``after`` taken ``seen`` of the way."""
    return [
        (b[0] + seen * (a[0] - b[0]), b[1] + seen * (a[1] - b[1]), a[2])
        for b, a in zip(before, after, strict=True)
    ]


def x_back_spread(planner: PosePlanner) -> tuple[float, float]:
    """The learned x−/coarse gain and its spread, as the daemon's status shows them."""
    saved = planner.model.estimates_json()["x/-/coarse/step"]
    assert isinstance(saved, dict)
    return saved["gain"][0], saved["gain_std"][0]


@pytest.mark.parametrize("source", ["learned", "restored"])
def test_the_audits_move_after_one_misread_burst_stays_in_the_travel(source: str) -> None:
    """The audit: one misread x−/coarse burst (a frame 0.42 of the way) passed the 5σ gate, set
    the gain to 0.30 ± 0.03 (truth 0.72) and lifted the probe; the move to x = −1.8 mm then
    played 1667 steps and the part went to x = −3.6 mm, out of the camera's view (here −4.1 mm).  Learned in
    this run, or restored from a state stored after it (one burst): the spread stays the seed's,
    the next burst is probed, and no plausible step carries the part past the travel."""
    start: Pose = (0.58e-3, -0.4e-3, 0.0)
    if source == "learned":
        planner = PosePlanner(ResponseModel(SEEDS, {}), TRAVEL, SQUARE)
        burst = AxisBurst("x", -1, 40, "coarse")
        before = [(start[0] + 40 * TRUE_GAIN * SEEDS[("x", "coarse")], start[1], 0.0)]
        planner.learn(burst, before, misread(before, Plate(before).burst(burst)))
        gain, spread = x_back_spread(planner)
        assert gain == pytest.approx(0.30, abs=0.01)  # the misreading is not hidden ...
        assert spread >= 0.9 * SEED_STD  # ... but one burst does not make it sure (was 0.03)
    else:
        model = ResponseModel(SEEDS, {})
        model.restore(
            {"x/-/coarse/step": {"radii_m": [0.0], "gain": [0.307], "gain_std": [0.0299], "bursts": 1}}
        )
        planner = PosePlanner(model, TRAVEL, SQUARE)
    target = (-1.8e-3, start[1], NAN)
    nxt = planner.next_burst([start], {1: target})
    assert isinstance(nxt, AxisBurst) and (nxt.axis, nxt.direction, nxt.mode) == ("x", -1, "coarse")
    end = Plate([start]).burst(nxt)[0]
    assert TRAVEL.contains(end[0], end[1]), end  # was x = −3.6 mm (1667 steps)
    assert end[0] >= target[0] - 0.1e-3  # probed: nowhere near past the target either
    # even at the seed's upper end (1 + 2 × 30 %), which the misreading cannot rule out
    assert start[0] - nxt.steps * (1 + 2 * SEED_STD) * SEEDS[("x", "coarse")] >= TRAVEL.x_m[0]


def run_corners(misread_at: int | None) -> tuple[list[Pose], int]:
    """Closed loop on a plate 0.72× its seed, from a fresh state, two parts through moves to the
    travel's corners (part 2 ends 50 µm from its edges there); the camera misreads burst
    ``misread_at`` (its frame 0.42 of the way).  Every move must end done; (every part's pose
    outside the travel after a burst, the bursts)."""
    planner = PosePlanner(ResponseModel(SEEDS, {}), TRAVEL, SQUARE)
    plate = Plate([(0.4e-3, 0.3e-3, 0.0), (-0.1e-3, 0.0, 0.0)])  # part 2 0.5 mm −x, 0.3 mm −y of 1
    count = 0
    for target in [
        (-1.85e-3, 1.9e-3, NAN),
        (2.2e-3, 1.0e-3, NAN),
        (2.0e-3, -2.05e-3, NAN),
        (0.0, -0.5e-3, NAN),
    ]:
        for _ in range(100):
            before = plate.poses
            nxt = planner.next_burst(before, {1: target})
            if isinstance(nxt, Finish):
                break
            after = plate.burst(nxt)
            planner.learn(nxt, before, misread(before, after) if count == misread_at else after)
            count += 1
        assert nxt == Finish("done", "every part within tolerance"), (misread_at, target, nxt)
    return [p for poses in plate.path for p in poses if not TRAVEL.contains(p[0], p[1])], count


def test_one_misread_burst_anywhere_never_drives_a_part_out_of_the_travel() -> None:
    """Whichever burst of the run the camera misreads, every part stays within the travel after
    every burst and every move ends done.  (The old planner learned 0.30 ± 0.03 from a misread
    coarse burst, trusted it in its travel cut and carried the parts up to 2.2 mm past the edge,
    out of the camera's view, for 6 of the run's 41 bursts misread.)"""
    outside, bursts = run_corners(None)
    assert not outside
    out = {k: found[:2] for k in range(bursts) if (found := run_corners(k)[0])}
    assert not out, out


def test_one_burst_read_on_two_parts_confirms_nothing() -> None:
    """Two parts read after one burst are one burst's readings, not two bursts agreeing: a
    misreading beyond the gate (both parts 5× the seed) reopened the prior around it and was
    learned (gain 5 ± 0.07), and one within it lifted the probe; neither does now."""
    beyond = PosePlanner(ResponseModel(SEEDS, {}), TRAVEL, SQUARE)
    poses: list[Pose] = [(0.0, 0.0, 0.0), (1.0e-3, 0.5e-3, 0.0)]
    burst = AxisBurst("x", -1, 30, "coarse")
    beyond.learn(burst, poses, misread(poses, Plate(poses, gain=1.0).burst(burst), seen=5.0))
    assert x_back_spread(beyond) == pytest.approx((1.0, SEED_STD))
    within = PosePlanner(ResponseModel(SEEDS, {}), TRAVEL, SQUARE)
    within.learn(burst, poses, misread(poses, Plate(poses).burst(burst)))
    nxt = within.next_burst(poses, {1: (-1.6e-3, 0.0, NAN)})
    gain, _ = x_back_spread(within)
    assert isinstance(nxt, AxisBurst) and nxt.steps * gain * SEEDS[("x", "coarse")] <= 1.6e-3 / 8 * (1 + 1e-9)


def test_a_confirmed_gain_is_not_moved_by_one_misreading_and_the_probe_lifts_on_two_alike() -> None:
    """One burst, then a second alike: the probe lifts and the spread narrows (to ~MODEL_STD).
    A misreading after many alike bursts leaves the gain where it was (it pulled a 0.72 learned
    from 9 bursts to 0.68, and three more true bursts left it at 0.69 ± 0.008, 4σ below the
    truth), and the travel cut doubts the gain until two bursts agree again (a burst towards
    the edge trusted the 0.68 and ended 22 µm past it)."""
    planner = PosePlanner(ResponseModel(SEEDS, {}), TRAVEL, SQUARE)
    poses: list[Pose] = [(2.0e-3, 0.0, 0.0)]
    target = (-1.0e-3, 0.0, NAN)
    lifted = []
    for k in range(9):
        plate = Plate(poses)
        burst = AxisBurst("x", -1, 50 + 10 * k, "coarse")
        planner.learn(burst, poses, plate.burst(burst))
        nxt = planner.next_burst(poses, {1: target})
        assert isinstance(nxt, AxisBurst)
        gain, _ = x_back_spread(planner)
        lifted.append(nxt.steps * gain * SEEDS[("x", "coarse")] > 3e-3 / 8 * (1 + 1e-9))
    assert lifted == [False] + [True] * 8
    gain, spread = x_back_spread(planner)
    assert gain == pytest.approx(TRUE_GAIN, rel=1e-3) and spread < 0.03
    burst = AxisBurst("x", -1, 300, "coarse")
    planner.learn(burst, poses, misread(poses, Plate(poses).burst(burst)))
    start: Pose = (-1.0e-3, 0.0, 0.0)
    nxt = planner.next_burst([start], {1: (-2.38e-3, 0.0, NAN)})
    assert isinstance(nxt, AxisBurst) and (nxt.axis, nxt.direction) == ("x", -1)
    end = Plate([start]).burst(nxt)[0]
    assert TRAVEL.contains(end[0], end[1]), end
    for _ in range(3):
        planner.learn(burst, poses, Plate(poses).burst(burst))
    gain, spread = x_back_spread(planner)
    assert abs(gain - TRUE_GAIN) < 2 * spread + 0.01 * TRUE_GAIN


def turning_model(gain: float = 1.0) -> ResponseModel:
    """A part at O turns in place (10 mrad per coarse step); beyond 1 mm every part orbits
    25 mrad per coarse step (no radial drift, any orientation): x and y as :data:`SEEDS`."""
    radii = (0.0, 0.5e-3, 1e-3, 3e-3)
    betas = tuple(math.pi / 2 * j / 4 for j in range(4))

    def table(orbit_mrad: tuple[float, ...], turn_mrad: tuple[float, ...]) -> TurnTable:
        orbit = gain * 1e-3 * np.array(orbit_mrad)[:, None] * np.ones((1, 4))
        turn = gain * 1e-3 * np.array(turn_mrad)[:, None] * np.ones((1, 4))
        return TurnTable(radii, betas, orbit, np.zeros_like(orbit), turn, math.pi / 2)

    return ResponseModel(
        SEEDS,
        {
            "coarse": table((0.0, 22.0, 25.0, 25.0), (10.0, 21.0, 25.0, 25.0)),
            "fine": table((0.0, 4.4, 5.0, 5.0), (2.0, 4.2, 5.0, 5.0)),
        },
    )


def test_a_turn_keeps_a_part_at_a_radius_no_burst_informed_within_the_travel() -> None:
    """Part 1 turns at O, where many bursts confirmed its turn (spread ~1 %); part 2, put down
    2.6 mm from O, orbits where nothing was learned: its gain there may be 1.5× the seed (within
    the seed's 2σ).  The turn's travel cut took part 1's spread for both and let part 2 orbit to
    the edge with 6 % to spare; it now takes part 2's own (the seed's 30 %)."""
    model = turning_model()
    for _ in range(10):  # part 1 alone at O, its coarse +θ turn as seeded
        model.learn("theta", 1, "coarse", 20, (0.0, 0.0, 0.0), (0.0, 0.0, 0.2))
    planner = PosePlanner(model, TRAVEL, SQUARE)
    poses: list[Pose] = [(0.0, 0.0, 0.0), (2.6e-3 * math.cos(-0.6), 2.6e-3 * math.sin(-0.6), 0.0)]
    nxt = planner.next_burst(poses, {1: (0.0, 0.0, 0.7)})
    assert isinstance(nxt, AxisBurst) and (nxt.axis, nxt.direction) == ("theta", 1)
    truth = turning_model(gain=1.5)
    end = truth.predict("theta", 1, nxt.mode, nxt.steps, poses[1])
    assert TRAVEL.contains(end[0], end[1]), end
