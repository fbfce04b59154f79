"""Design files (plan → file → simulate), amplifier files and the waveform design search."""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest

from feeder.cli import main
from feeder.design import DesignProblem, design_waveform, margins
from feeder.errors import InputError
from feeder.parts import Part
from feeder.planner import plant_step
from feeder.plant.amplifier import (
    AMPLIFIER_MODELS,
    AmplifierLimits,
    OutputStage,
    load_amplifier,
    resolve_amplifier,
)
from feeder.waveform import Waveform, load_waveform, read_waveform_tables, write_waveform_file

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "waveforms" / "paper-100hz-200vpp.toml"


def run_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict:
    capsys.readouterr()
    assert main([*argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_plan_file_round_trip_reproduces_the_predicted_step(tmp_path, capsys):
    out = tmp_path / "design.toml"
    planned = run_json(capsys, "plan", "--part", "300x300x50", "--distance-m", "100e-6", "--out", str(out))
    tables = read_waveform_tables(out)
    assert tables["prediction"]["predicted_step_m"] == planned["predicted_step_m"]
    assert tables["prediction"]["tau_pa"] == pytest.approx(22.18e9)
    assert tables["prediction"]["adhesion_work_j_m2"] == 0.0
    assert tables["amplifier"]["model"] == "firmware_sim"
    assert tables["plan"]["steps"] == planned["steps"]
    wave = load_waveform(out)  # the extra tables do not disturb the waveform reader
    assert wave.frequency_hz == planned["frequency_hz"]
    assert wave.amplitude_vpp == planned["amplitude_vpp"]
    sim = run_json(capsys, "simulate", "--part", "300x300x50", "--waveform", str(out), "--periods", "50")
    assert sim["step_mean_m"] == pytest.approx(planned["predicted_step_m"], rel=0.01)
    shown = run_json(capsys, "waveform", "show", str(out))
    assert shown["frequency_hz"] == planned["frequency_hz"]
    exported = run_json(capsys, "waveform", "export", str(out), "--format", "anc300")
    assert exported["points"] == 256


def test_plan_file_for_the_anc300_plays_above_the_default_amplifier_frequency(tmp_path, capsys):
    out = tmp_path / "anc.toml"
    planned = run_json(
        capsys,
        "plan",
        "--part",
        "300x300x50",
        "--distance-m",
        "100e-6",
        "--amplifier",
        "anc300",
        "--out",
        str(out),
    )
    assert planned["frequency_hz"] > AMPLIFIER_MODELS["firmware_sim"].max_frequency_hz
    # simulate and show check the file against its own [amplifier], not the 2 kHz default
    sim = run_json(capsys, "simulate", "--part", "300x300x50", "--waveform", str(out), "--periods", "50")
    assert sim["step_mean_m"] == pytest.approx(planned["predicted_step_m"], rel=0.01)
    assert load_amplifier(out) == AMPLIFIER_MODELS["anc300"]


def test_waveform_file_tables_are_written_and_read_back(tmp_path):
    path = tmp_path / "w.toml"
    wave = Waveform(frequency_hz=250.0, amplitude_vpp=120.0, flyback_shape="linear", flyback_s=2e-4)
    write_waveform_file(
        path,
        wave,
        {"note": {"text": 'a "quoted" µm', "values": [1.5, 2], "ok": True, "skipped": None}},
        comment="two\nlines",
    )
    assert load_waveform(path) == wave
    assert read_waveform_tables(path) == {"note": {"text": 'a "quoted" µm', "values": [1.5, 2], "ok": True}}
    with pytest.raises(ValueError):
        write_waveform_file(path, wave, {"note": {"x": math.nan}})
    assert load_waveform(path) == wave  # a failed write leaves the old file whole


def test_amplifier_from_names_and_files(tmp_path):
    assert resolve_amplifier("paper") == ("firmware_sim", AMPLIFIER_MODELS["firmware_sim"])
    assert resolve_amplifier("anc300")[1].v_max_v == 150.0
    flat = tmp_path / "amp.toml"
    flat.write_text("v_max_v = 120.0\ncurrent_limit_a = 0.2\n")
    name, limits = resolve_amplifier(str(flat))
    assert name == str(flat)
    assert limits == AmplifierLimits(v_max_v=120.0, current_limit_a=0.2)
    based = tmp_path / "based.toml"
    based.write_text('[amplifier]\nmodel = "anc300"\ncurrent_limit_a = 0.3\n')
    assert load_amplifier(based).max_frequency_hz == 10_000.0
    assert load_amplifier(based).current_limit_a == 0.3
    bad = tmp_path / "bad.toml"
    bad.write_text("v_max_volts = 120.0\n")
    with pytest.raises(InputError, match=r"bad.toml: v_max_volts"):
        load_amplifier(bad)
    bad.write_text("current_limit_a = -1\n")
    with pytest.raises(InputError, match=r"bad.toml: current_limit_a"):
        load_amplifier(bad)
    with pytest.raises(InputError, match="--amplifier"):
        resolve_amplifier("anc301")


def test_an_unknown_amplifier_model_is_no_base_for_missing_limits(tmp_path):
    typo = tmp_path / "typo.toml"
    typo.write_text('[amplifier]\nmodel = "anc301"\ncurrent_limit_a = 0.3\n')
    with pytest.raises(InputError, match=r"typo.toml: \[amplifier\].model.*'anc301'.*v_max_v"):
        load_amplifier(typo)
    # a design file written for an amplifier given as a file names that file and lists every limit
    limits = AmplifierLimits(v_max_v=120.0, current_limit_a=0.2)
    whole = tmp_path / "whole.toml"
    whole.write_text("[amplifier]\nmodel = \"my-amp.toml\"\n"
                     + "".join(f"{k} = {float(v)!r}\n" for k, v in asdict(limits).items()))  # fmt: skip
    assert load_amplifier(whole) == limits


def test_design_cli_rejects_a_bad_amplifier_before_writing(tmp_path, capsys):
    out = tmp_path / "F.toml"
    assert main(["waveform", "design", "--part", "500x500x50", "--amplifier", "nope", "--out", str(out)]) == 2
    assert "--amplifier" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.timeout(30)
def test_output_stage_follows_a_command_at_exactly_its_slope_limit():
    # a linear flyback commanded at exactly I_max/C once made the ramp loop spin forever on a rounding
    limits, c, rate = AmplifierLimits(), 1e-6, 100e3
    wave = Waveform(
        frequency_hz=rate / 300,
        amplitude_vpp=200.0,
        flyback_shape="linear",
        flyback_s=200.0 / limits.max_slope_v_per_s(c),
    )
    command = wave.voltage_at_phase(np.arange(1, 3 * 300 + 1) / 300)
    out = OutputStage(limits, c, rate, initial_v=0.0).advance(command)
    d = limits.max_slope_v_per_s(c) / rate
    assert np.all(np.abs(np.diff(out)) <= d * (1 + 1e-9))
    np.testing.assert_allclose(out, command, atol=1e-9 * 200)
    step = plant_step(
        Waveform(
            frequency_hz=341.99518933533966,
            amplitude_vpp=200.0,
            flyback_shape="linear",
            flyback_s=0.00036363636363636356,
        ),
        105.25,
        0.8,
    )
    assert step > 0


def test_design_beats_the_paper_waveform_and_simulate_confirms(tmp_path, capsys):
    """Acceptance of #18 on the current-limited family (the full family: test below, --runslow)."""
    part = "500x500x50"
    paper = run_json(capsys, "simulate", "--part", part, "--waveform", str(PAPER), "--periods", "50")
    out = tmp_path / "F.toml"
    design = run_json(
        capsys,
        "waveform",
        "design",
        "--part",
        part,
        "--amplifier",
        "paper",
        "--objective",
        "max-step",
        "--shapes",
        "current-limited",
        "--out",
        str(out),
    )
    assert design["predicted_step_m"] >= paper["step_mean_m"]
    lo, hi = design["predicted_step_band_m"]
    assert lo < design["predicted_step_m"] < hi
    assert design["amplitude_vpp"] <= 200.0 and design["frequency_hz"] <= 2000.0
    sim = run_json(capsys, "simulate", "--part", part, "--waveform", str(out), "--periods", "50")
    assert sim["step_mean_m"] == pytest.approx(design["predicted_step_m"], rel=0.02)
    assert read_waveform_tables(out)["design"]["objective"] == "max-step"


@pytest.mark.slow
def test_design_acceptance_command_in_full(tmp_path, capsys):
    out = tmp_path / "F.toml"
    design = run_json(
        capsys,
        "waveform",
        "design",
        "--part",
        "500x500x50",
        "--amplifier",
        "paper",
        "--objective",
        "max-step",
        "--out",
        str(out),
    )
    sim = run_json(capsys, "simulate", "--part", "500x500x50", "--waveform", str(out), "--periods", "50")
    assert design["predicted_step_m"] >= 3.298e-6
    assert sim["step_mean_m"] == pytest.approx(design["predicted_step_m"], rel=0.02)


def test_anc300_design_uses_whole_table_steps_within_its_rail():
    model, limits = resolve_amplifier("anc300")
    problem = DesignProblem(Part.parse("300x300x50"), amplifier_model=model, amplifier=limits)
    design = design_waveform(
        problem, "max-step", shapes=("linear",), grid_points=(5, 5), refine_evaluations=25
    )
    w = design.waveform
    assert design.table_points == 256
    steps = w.flyback_s * w.frequency_hz * 256
    assert steps == pytest.approx(round(steps), abs=1e-6) and round(steps) >= 1
    assert w.max_voltage_v <= 150.0 and w.frequency_hz <= 10_000.0
    assert w.frequency_hz == round(w.frequency_hz)  # an ANC300 is set in whole hertz
    # the flyback draws no more than the current limit (it is a shape the amplifier follows)
    assert design.margins["current_margin"] >= 1.0 - 1e-9
    assert design.verified_step_mean_m == pytest.approx(design.predicted_step_m, rel=0.01)


def test_objectives_do_what_they_say():
    problem = DesignProblem(Part.parse("300x300x50"))
    effort = {"shapes": ("current-limited",), "grid_points": (5, 5), "refine_evaluations": 25}
    step = design_waveform(problem, "max-step", **effort)
    speed = design_waveform(problem, "max-speed", **effort)
    steady = design_waveform(problem, "min-scatter", **effort)

    def width(d):
        lo, hi = d.predicted_step_band_m
        return (hi - lo) / d.predicted_step_m

    assert speed.speed_m_s >= step.speed_m_s
    assert step.predicted_step_m >= speed.predicted_step_m
    assert width(steady) <= width(step)
    assert steady.predicted_step_band_m[0] > 0
    # margins are what they claim: the flyback acceleration breaks the part loose
    m = margins(step.waveform, problem)
    assert m["flyback_margin"] > 1.0 and m["ramp_margin"] > 1.0


def test_a_translation_axis_of_the_planar_plant_is_the_1d_plant():
    """DESIGN §9: driving x (or y) alone moves the part exactly as the 1-D plant does."""
    from feeder.axis_design import run_axis_waveform
    from feeder.plant.planar import PlanarPart
    from feeder.plant.plant import run_waveform
    from feeder.plant.stick_slip import Friction

    friction = Friction(105.0, 0.8)
    wave = Waveform(frequency_hz=500.0, amplitude_vpp=180.0)
    part = PlanarPart.from_part(Part.parse("500x500x50"), friction, (1e-3, -2e-3, 0.3))
    reference = run_waveform(friction, wave, 4).steps_m
    along_x = run_axis_waveform(part, wave, "x", 4).pose_changes
    along_y = run_axis_waveform(part, wave, "y", 4).pose_changes
    assert reference.min() > 1e-6
    np.testing.assert_allclose(along_x[:, 0], reference, rtol=1e-6)
    np.testing.assert_allclose(along_y[:, 1], reference, rtol=1e-6)
    assert np.abs(along_x[:, 1:]).max() < 1e-12 and np.abs(along_y[:, [0, 2]]).max() < 1e-12


def test_theta_design_is_confirmed_by_simulate_and_depends_on_the_distance_from_o(tmp_path, capsys):
    from feeder.axis_design import design_axis, run_axis_waveform, write_axis_design
    from feeder.plant.planar import PlanarPart
    from feeder.plant.stick_slip import Friction

    model, limits = resolve_amplifier("paper")
    problem = DesignProblem(Part.parse("500x500x50"), amplifier_model=model, amplifier=limits)
    pose = (1.5e-3, 0.0, 0.0)
    design = design_axis(problem, "theta", pose=pose, shapes=("current-limited",), grid_points=(4, 4),
                         refine_evaluations=12)  # fmt: skip
    lo, hi = design.turn_band_rad
    assert 0 < lo <= design.turn_rad <= hi
    out = tmp_path / "theta.toml"
    write_axis_design(out, problem, design)
    tables = read_waveform_tables(out)
    expected = {"name": "theta", "channel": 3, "pose": list(pose), "radius_m": 1.5e-3, "lever_arm_m": 2e-3,
                "part_shape": "rectangle", "model": "planar-plant"}  # fmt: skip
    assert tables["axis"] == expected
    assert tables["prediction"]["predicted_turn_rad"] == design.turn_rad
    sim = run_json(capsys, "simulate", "--part", "500x500x50", "--waveform", str(out), "--axis", "theta",
                   "--pose", "1.5e-3,0,0", "--periods", "12")  # fmt: skip
    assert sim["model"] == "planar-plant"
    assert sim["turn_mean_rad"] == pytest.approx(design.turn_rad, rel=0.01)
    assert sim["step_mean_m"] == pytest.approx(design.design.predicted_step_m, rel=0.01)
    # the same waveform barely turns a part sitting on O (the dead zone, DESIGN §9)
    a_s = problem.breakaway_accel_m_s2()[0]
    at_o = PlanarPart.from_part(problem.part, Friction(a_s, problem.kinetic_ratio))
    turn_at_o = run_axis_waveform(at_o, design.design.waveform, "theta", 3, limits).turns_rad.mean()
    assert abs(turn_at_o) < 0.2 * design.turn_rad


def test_axis_design_cli_refuses_bad_axes_before_writing(tmp_path, capsys):
    out = tmp_path / "F.toml"
    base = ["waveform", "design", "--part", "500x500x50", "--out", str(out)]
    assert main([*base, "--axes", "x,q"]) == 2
    assert "--axes" in capsys.readouterr().err
    assert main([*base, "--axis", "theta", "--objective", "min-scatter"]) == 2
    assert "--objective" in capsys.readouterr().err
    assert main([*base, "--axes", "x,x"]) == 2
    assert not list(tmp_path.iterdir())
