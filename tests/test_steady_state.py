"""Where a run's per-period steps reach their steady state (feeder/plant/steady_state.py), and
what ``feeder simulate`` and ``feeder sweep`` report for a part that slides through whole periods."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from feeder.cli import main
from feeder.contact.breakaway import contact
from feeder.parts import Part
from feeder.plant.ideal_plate import linear_flyback_step, sawtooth_motion
from feeder.plant.steady_state import ideal_steady_steps, steady_start
from feeder.plant.stick_slip import Friction, StickSlip

PAPER = Path(__file__).resolve().parents[1] / "waveforms" / "paper-100hz-200vpp.toml"
A_S = contact(Part.parse("500x500x50")).breakaway_accel_m_s2
# the review's drive: 2 kHz, 14 µm, 0.35 ms linear flyback (longer than the 0.15 ms rise)
SLIDING = {"stroke": 14e-6, "frequency": 2000.0, "flyback": 3.5e-4}
SLIDING_ARGS = ["simulate", "--part", "500x500x50", "--ideal", "--stroke-m", "14e-6",
                "--frequency-hz", "2000", "--flyback-s", "3.5e-4", "--json"]  # fmt: skip


def ideal_steps(stroke: float, frequency: float, flyback: float, periods: int) -> np.ndarray:
    """Per-period steps of one long run of the event-driven solver (the reference)."""
    motion = sawtooth_motion(stroke, frequency, flyback, "linear", periods)
    rel = StickSlip(Friction(A_S)).advance(motion.accel_m_s2[0], motion.duration_s[0], motion.jump_m_s[0])
    return np.diff(
        np.concatenate(([0.0], rel[motion.intervals_per_period - 1 :: motion.intervals_per_period]))
    )


def test_steady_start_finds_the_settled_tail_and_needs_two_periods_of_it() -> None:
    runs = [[5.0, 2.0, 2.0, 2.0], [38.0, 29.0, 21.0, 12.0], [1.0, 1.0, 1.0, 1.0], [9.0, 3.0, 3.0, 3.0000001]]
    start, settled = steady_start(np.array(runs))
    assert start.tolist() == [1, 3, 1, 1] and settled.tolist() == [True, False, True, True]
    start, settled = steady_start(np.array([4.0, 4.0]))  # two periods cannot show it
    assert start.tolist() == [1] and settled.tolist() == [False]


def test_a_part_that_re_sticks_every_period_is_steady_from_the_second_and_the_closed_form() -> None:
    found = ideal_steady_steps(np.array([14e-6, 8e-6]), 100.0, 3.5e-4, "linear", A_S, 0.8)
    closed = linear_flyback_step(np.array([14e-6, 8e-6]), 0.01 - 3.5e-4, 3.5e-4, 0.8 * A_S)
    np.testing.assert_allclose(found.step_m, closed, rtol=1e-9)
    assert found.transient_periods.tolist() == [1, 1] and found.settled.all()


def test_a_part_sliding_through_whole_periods_settles_on_the_long_runs_step_with_the_other_sign() -> None:
    """The second period (+29.6 µm) was reported as the steady state; the part settles on
    −18.1 µm from period 9 on (a 400-period run of the event-driven solver)."""
    reference = ideal_steps(SLIDING["stroke"], SLIDING["frequency"], SLIDING["flyback"], 400)
    assert reference[1] > 29e-6 and reference[-1] < -18e-6
    found = ideal_steady_steps(
        SLIDING["stroke"], SLIDING["frequency"], SLIDING["flyback"], "linear", A_S, 0.8
    )
    assert found.settled[0] and found.step_m[0] == pytest.approx(reference[-1], rel=1e-9)
    assert found.transient_periods[0] == 8
    np.testing.assert_allclose(reference[8:], reference[-1], rtol=1e-3)
    assert abs(reference[7] - reference[-1]) > 1e-3 * abs(reference).max()


def test_simulate_reports_the_settled_step_and_warns_when_the_run_is_too_short(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main([*SLIDING_ARGS, "--periods", "20"]) == 0
    out = json.loads(capsys.readouterr().out)
    reference = ideal_steps(SLIDING["stroke"], SLIDING["frequency"], SLIDING["flyback"], 20)
    assert out["steady"] is True and out["transient_periods"] == 8
    assert out["step_mean_m"] == pytest.approx(reference[8:].mean(), rel=1e-12) and out["step_mean_m"] < 0
    assert not any("not settled" in w for w in out["warnings"])
    assert main([*SLIDING_ARGS, "--periods", "5"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["steady"] is False
    assert any("has not settled in 5 periods" in w and "--periods" in w for w in out["warnings"])
    assert main([*SLIDING_ARGS[:-1], "--periods", "5"]) == 0
    (step,) = [line for line in capsys.readouterr().out.splitlines() if line.lstrip().startswith("step")]
    assert "NOT settled" in step and "±" not in step  # one period: no "± 0.0000" certainty


def test_simulate_with_scatter_or_on_theta_does_not_judge_the_steady_state(
    capsys: pytest.CaptureFixture[str],
) -> None:
    args = ["simulate", "--part", "300x300x50", "--ideal", "--axis", "theta", "--stroke-rad", "7e-3",
            "--frequency-hz", "100", "--flyback-s", "3.5e-4", "--pose=2e-3,0,0", "--periods", "4",
            "--json"]  # fmt: skip
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["steady"] is None and out["transient_periods"] == 1
    plant = ["simulate", "--part", "300x300x50", "--waveform", str(PAPER), "--periods", "3",
             "--scatter", "0.05", "--json"]  # fmt: skip
    assert main(plant) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["steady"] is None and out["transient_periods"] == 1
    assert out["step_mean_m"] == pytest.approx(np.mean(out["steps_m"][1:]), rel=1e-12)
    assert main(args[:-1]) == 0  # the text says the same: no steady state claimed
    (step,) = [line for line in capsys.readouterr().out.splitlines() if line.lstrip().startswith("step")]
    assert "steadiness not judged" in step and "steady state" not in step


def test_an_ideal_sweep_runs_a_sliding_drive_until_it_settles(tmp_path: Path) -> None:
    """It reported the first 5 periods' mean, +21 µm, for a part that settles on −18.1 µm."""
    pd = pytest.importorskip("pandas", reason="the sweep extra (pandas, pyarrow, dask) is not installed")
    pytest.importorskip("pyarrow", reason="the sweep extra (pyarrow) is not installed")
    from feeder.sweep import run_sweep
    from feeder.sweep_spec import load_spec

    spec = tmp_path / "s.toml"
    spec.write_text(
        '[sweep]\nmodel = "ideal"\nperiods = 5\n[parameters]\nfrequency_hz = [100.0, 2000.0]\n'
        'amplitude_vpp = [200.0]\nflyback_shape = ["linear"]\nflyback_s = [3.5e-4]\npart = ["500x500x50"]\n'
    )
    run_sweep(load_spec(spec), tmp_path / "s.parquet", serial=True)
    rows = pd.read_parquet(tmp_path / "s.parquet").set_index("frequency_hz")
    reference = ideal_steps(SLIDING["stroke"], SLIDING["frequency"], SLIDING["flyback"], 400)
    assert rows.loc[2000.0, "step_mean_m"] == pytest.approx(reference[-1], rel=1e-9)
    assert rows.loc[2000.0, "transient_periods"] == 8 and bool(rows.loc[2000.0, "steady"])
    closed = linear_flyback_step(14e-6, 0.01 - 3.5e-4, 3.5e-4, 0.8 * A_S)
    assert rows.loc[100.0, "step_mean_m"] == pytest.approx(closed, rel=1e-9)
    assert rows.loc[100.0, "transient_periods"] == 1 and bool(rows.loc[100.0, "steady"])
