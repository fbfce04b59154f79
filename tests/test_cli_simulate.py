"""``feeder simulate`` on the command line: design-file defaults and warnings, text output,
the options' ranges (plant and ideal-plate physics: tests/test_plant.py, tests/test_planar.py)."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from feeder.cli import main
from feeder.plant.stack import StackParameters

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "waveforms" / "paper-100hz-200vpp.toml"

# The θ file of `feeder waveform design --part 500x500x50 --amplifier paper --axes x,y,theta
# --radius-m 1.5mm --out plate.toml` (plate-theta.toml; [design] and [margins] left out).
THETA_DESIGN = """\
[waveform]
shape = "sawtooth"
frequency_hz = 888.7076179045412
amplitude_vpp = 154.70789944566792
offset_v = 0.0
flyback_shape = "current-limited"
direction = "forward"

[amplifier]
model = "firmware_sim"
v_min_v = 0.0
v_max_v = 200.0
slew_rate_v_per_s = 2000000.0
current_limit_a = 0.55
min_frequency_hz = 1.0
max_frequency_hz = 2000.0

[stack]
gain_m_per_v = 7e-08
capacitance_f = 1e-06
output_resistance_ohm = 8.0
resonance_hz = 30000.0
damping_ratio = 0.1

[prediction]
written_by = "feeder waveform design"
part = "500x500x50"
density_kg_m3 = 2330.0
support = "flat"
surface = "embedded"
tau_pa = 22180000000.0
tau_band_pa = 3150000000.0
tau_adhesion_work_j_m2 = 0.0
adhesion_work_j_m2 = 0.0
kinetic_ratio = 0.8
breakaway_accel_m_s2 = 105.2519201586756
breakaway_accel_band_m_s2 = [90.30405954100976, 120.19978077634143]
model = "planar-plant"
predicted_step_m = 3.5535919397192888e-06
predicted_step_band_m = [2.379263689229482e-06, 4.6264556232928025e-06]
predicted_turn_rad = 0.0032088533636247057
predicted_turn_band_rad = [0.002462369246513121, 0.0038073719409605945]
predicted_pose_change = [-2.0850672509844461e-07, 3.5453903675413145e-06, 0.003208853363624706]

[axis]
name = "theta"
channel = 3
pose = [0.0015, 0.0, 0.0]
radius_m = 0.0015
lever_arm_m = 0.002
part_shape = "rectangle"
model = "planar-plant"
"""

IDEAL = ["simulate", "--part", "300x300x50", "--ideal", "--stroke-m", "5e-6", "--frequency-hz", "100",
         "--periods", "3"]  # fmt: skip
IDEAL_THETA = [*IDEAL[:4], *IDEAL[6:], "--axis", "theta"]  # --stroke-m is x's and y's


@pytest.fixture
def theta_design(tmp_path: Path) -> Path:
    path = tmp_path / "plate-theta.toml"
    path.write_text(THETA_DESIGN)
    return path


def run_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict:
    capsys.readouterr()
    assert main([*argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def refused(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """Exit 2 with one line on stderr (argparse's own errors exit through SystemExit)."""
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exit_:
        code = exit_.code  # type: ignore[assignment]
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, (argv, code, err)
    return err


def contradictions(data: dict) -> list[str]:
    return [w for w in data["warnings"] if "contradicts" in w]


# --- a design file's [axis] and [prediction] -------------------------------------------------------


def test_design_file_sets_axis_and_pose_and_reproduces_its_prediction(theta_design, capsys):
    """`simulate --waveform plate-theta.toml` runs θ at the file's pose (it ran x at O before),
    and then gives the file's predicted turn (3.21 mrad, not 0.15 at O)."""
    sim = run_json(
        capsys, "simulate", "--part", "500x500x50", "--waveform", str(theta_design), "--periods", "5"
    )
    assert sim["axis"] == "theta" and sim["model"] == "planar-plant"
    assert sim["pose_start"] == [1.5e-3, 0.0, 0.0]
    assert sim["turn_mean_rad"] == pytest.approx(3.2089e-3, rel=0.01)
    assert sim["step_mean_m"] == pytest.approx(3.5536e-6, rel=0.01)
    assert contradictions(sim) == []
    explicit = run_json(capsys, "simulate", "--part", "500x500x50", "--waveform", str(theta_design),
                        "--axis", "theta", "--pose", "1.5e-3,0,0", "--periods", "5")  # fmt: skip
    assert explicit["poses"] == sim["poses"] and contradictions(explicit) == []
    # --axis alone takes the pose from the file too (it ran at O: 0.15 mrad per period)
    axis_only = run_json(capsys, "simulate", "--part", "500x500x50", "--waveform", str(theta_design),
                         "--axis", "theta", "--periods", "5")  # fmt: skip
    assert axis_only["poses"] == sim["poses"]


def test_options_contradicting_the_design_file_are_warned_in_json_and_text(theta_design, capsys):
    base = ["simulate", "--waveform", str(theta_design), "--periods", "2"]
    sim = run_json(capsys, *base, "--part", "500x500x50", "--axis", "x")
    [warning] = contradictions(sim)
    assert warning.startswith("--axis x contradicts") and "[axis] name = 'theta'" in warning
    sim = run_json(capsys, *base, "--part", "500x500x50", "--pose", "1e-3,0,0")
    [warning] = contradictions(sim)
    assert warning.startswith("--pose 0.001,0,0 contradicts") and "0.0015,0,0" in warning
    sim = run_json(capsys, *base, "--part", "300x300x50", "--support", "grooved")
    assert [w.split()[0] for w in contradictions(sim)] == ["--part", "--support"]
    assert "'500x500x50'" in contradictions(sim)[0]
    # the same in the text output
    capsys.readouterr()
    assert main([*base, "--part", "300x300x50", "--axis", "x", "--pose", "1e-3,0,0"]) == 0
    out = capsys.readouterr().out
    assert "warning: --axis x contradicts" in out and "warning: --part 300x300x50 contradicts" in out


def test_pose_is_warned_only_where_the_prediction_depends_on_it(tmp_path, capsys):
    """A translation design (x, y) steps the same anywhere: another --pose is no contradiction."""
    path = tmp_path / "plate-x.toml"
    path.write_text(
        THETA_DESIGN.replace('name = "theta"', 'name = "x"').replace("channel = 3", "channel = 1")
    )
    base = ["simulate", "--part", "500x500x50", "--waveform", str(path), "--periods", "2"]
    sim = run_json(capsys, *base)
    assert sim["axis"] == "x" and sim["model"] == "plant" and sim["pose_start"] == [1.5e-3, 0.0, 0.0]
    assert contradictions(run_json(capsys, *base, "--pose", "0,0,0")) == []
    # a plain waveform file has no [axis]: x at O, as before
    plain = run_json(capsys, "simulate", "--part", "500x500x50", "--waveform", str(PAPER), "--periods", "2")
    assert plain["axis"] == "x" and plain["pose_start"] == [0.0, 0.0, 0.0] and contradictions(plain) == []


def test_options_the_design_file_axis_rules_out_name_it(theta_design, capsys):
    err = refused(capsys, ["simulate", "--part", "500x500x50", "--waveform", str(theta_design), "--plot",
                           str(theta_design.with_suffix(".png"))])  # fmt: skip
    assert "--plot" in err and "[axis]" in err


def test_an_ideal_theta_plate_takes_the_design_files_stroke_over_its_lever_arm(theta_design, capsys):
    """`--ideal` with a θ design file asked for --stroke-rad: the file's stroke (m) over its
    [axis] lever_arm_m (2 mm) is the plate's turn."""
    base = ["simulate", "--part", "500x500x50", "--waveform", str(theta_design), "--ideal", "--periods", "3"]
    derived = run_json(capsys, *base)
    assert 1e-3 < derived["stroke_rad"] < 2e-2  # ~14 µm over 2 mm, not the metres themselves
    design = tomllib.loads(theta_design.read_text())
    full_m = StackParameters().gain_m_per_v * design["waveform"]["amplitude_vpp"]
    full_rad = full_m / design["axis"]["lever_arm_m"]
    given = run_json(capsys, *base, "--stroke-rad", repr(full_rad))
    assert given["poses"] == derived["poses"] and given["stroke_rad"] == derived["stroke_rad"]


@pytest.mark.parametrize("line, bad, field", [
    ('name = "theta"', 'name = "z"', "[axis].name"),
    ('name = "theta"', "name = 3", "[axis].name"),
    ("pose = [0.0015, 0.0, 0.0]", "pose = [0.0015, 0.0]", "[axis].pose"),
    ("pose = [0.0015, 0.0, 0.0]", "pose = [5.0, 0.0, 0.0]", "[axis].pose"),
    ("pose = [0.0015, 0.0, 0.0]", 'pose = "1.5e-3,0,0"', "[axis].pose"),
    ("pose = [0.0015, 0.0, 0.0]", 'pose = [0.0015, 0.0, "0"]', "[axis].pose"),
])  # fmt: skip
def test_bad_axis_table_is_refused_naming_the_field(tmp_path, capsys, line, bad, field):
    path = tmp_path / "bad.toml"
    path.write_text(THETA_DESIGN.replace(line, bad))
    err = refused(capsys, ["simulate", "--part", "500x500x50", "--waveform", str(path)])
    assert f"{path}: {field}" in err


# --- text output: warnings and written files ---------------------------------------------------------


def test_text_output_tells_every_warning_and_the_files_it_wrote(tmp_path, capsys):
    argv = ["simulate", "--part", "80x80x50", "--ideal", "--stroke-m", "5e-6", "--frequency-hz", "100",
            "--flyback-s", "1e-4", "--periods", "3"]  # fmt: skip
    warnings = run_json(capsys, *argv)["warnings"]
    assert any("asperities" in w for w in warnings)
    png = tmp_path / "trace.png"
    assert main([*argv, "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    for warning in warnings:
        assert f"warning: {warning}" in out
    assert f"wrote {png}" in out and png.stat().st_size > 0
    assert main([*IDEAL_THETA, "--flyback-s", "1e-4", "--stroke-rad", "7e-3",
                 "--periods", "2", "--map", str(tmp_path / "map.png"), "--map-points", "2"]) == 0  # fmt: skip
    assert f"wrote {tmp_path / 'map.png'}" in capsys.readouterr().out


def test_closed_form_beyond_its_validity_is_not_printed_as_nan(capsys):
    """t_f > t_r: the closed form does not apply (JSON null); the text says so instead of "nan"."""
    assert run_json(capsys, *IDEAL, "--flyback-s", "9e-3")["closed_form_step_m"] is None
    assert main([*IDEAL, "--flyback-s", "9e-3"]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out and "closed form n/a (flyback longer than the rise" in out
    assert main([*IDEAL, "--flyback-s", "1e-4"]) == 0
    assert "closed form 4.2084" in capsys.readouterr().out  # S(1 + t_f/t_r) − a_k·t_f²


# --- ranges ----------------------------------------------------------------------------------------


def test_help_states_each_range(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps the help
    for stated in ("0 < S ≤ 0.001 m", "0.001–1e+06", "from 1e-09 s to below the period",
                   "0 < THETA ≤ 0.1 rad", "|X|, |Y| ≤ 0.1 m, |PSI| ≤ 2π", "at most 0.1 m",
                   "grid points per side, 2–41", "above 0 and at most 1"):  # fmt: skip
        assert stated in text, stated


@pytest.mark.parametrize("option, value", [
    ("--stroke-m", "1"), ("--stroke-m", "2mm"), ("--stroke-m", "0"), ("--stroke-m", "-5e-6"),
    ("--frequency-hz", "1e9"), ("--frequency-hz", "1e-300"), ("--flyback-s", "1e-300"),
    ("--flyback-s", "nan"), ("--stroke-rad", "10"), ("--stroke-rad", "0"), ("--pose", "1,0,0"),
    ("--pose", "0,-0.2,0"), ("--pose", "0,0,7"), ("--map-extent-m", "10"), ("--map-extent-m", "0"),
    ("--map-points", "100"),
])  # fmt: skip
def test_absurd_values_are_refused_naming_the_option(capsys, option, value):
    argv = [*IDEAL_THETA, "--flyback-s", "1e-4", "--stroke-rad", "7e-3", "--json"]
    argv = [a for i, a in enumerate(argv) if option not in (a, argv[i - 1])]
    err = refused(capsys, [*argv, f"{option}={value}"])
    assert option in err


def test_range_ends_and_units_are_accepted(capsys):
    big = run_json(capsys, *IDEAL[:4], "--stroke-m", "1mm", "--frequency-hz", "1e6", "--flyback-s", "1e-9",
                   "--periods", "2")  # fmt: skip
    assert big["stroke_m"] == 1e-3 and big["frequency_hz"] == 1e6
    same = run_json(capsys, *IDEAL, "--flyback-s", "1e-4")
    assert run_json(capsys, *IDEAL, "--flyback-s", "1e-4", "--stroke-m", "5um")["steps_m"] == same["steps_m"]
    turn = run_json(capsys, *IDEAL_THETA, "--flyback-s", "3.5e-4", "--stroke-rad", "0.1",
                    "--pose=-0.1,0.1,-6.28")  # fmt: skip
    assert turn["stroke_rad"] == 0.1 and turn["pose_start"] == [-0.1, 0.1, -6.28]
    err = refused(capsys, [*IDEAL, "--flyback-s", "0.01"])  # not below the period
    assert "--flyback-s" in err


def test_a_pose_takes_units(capsys):
    """DESIGN §12: lengths and angles accept units, a pose's too."""
    argv = [*IDEAL_THETA, "--flyback-s", "3.5e-4", "--stroke-rad", "7e-3", "--periods", "2"]
    plain = run_json(capsys, *argv, "--pose", "1.5e-3,-2e-4,0.17453292519943295")
    units = run_json(capsys, *argv, "--pose", "1.5mm,-200um,10deg")
    assert units["pose_start"] == pytest.approx(plain["pose_start"], rel=1e-15)
    for got, want in zip(units["poses"], plain["poses"], strict=True):
        assert got == pytest.approx(want, rel=1e-12)
    err = refused(capsys, [*argv, "--pose", "1.5mm,0"])
    assert "--pose" in err and "three values" in err
    assert "--pose" in refused(capsys, [*argv, "--pose", "1.5kg,0,0"])


@pytest.mark.parametrize("extra, option", [
    (["--stroke-m", "5e-6"], "--stroke-m"), (["--frequency-hz", "200"], "--frequency-hz"),
    (["--ideal", "--stroke-m", "5e-6", "--flyback-s", "1e-4"], "--flyback-s"),
])  # fmt: skip
def test_drive_options_nothing_would_read_are_refused(capsys, extra, option):
    """They were silently ignored: the plant plays the waveform file, which also gives an ideal
    plate's frequency and flyback."""
    argv = ["simulate", "--part", "300x300x50", "--waveform", str(PAPER), "--periods", "2", *extra]
    err = refused(capsys, argv)
    assert err.startswith(f"feeder simulate: error: {option}:")


@pytest.mark.parametrize("extra, option, words", [
    (["--axis", "theta", "--stroke-rad", "7e-3", "--stroke-m", "5e-6"], "--stroke-m", "--stroke-rad"),
    (["--stroke-m", "5e-6", "--stroke-rad", "7e-3"], "--stroke-rad", "--stroke-m"),
    (["--stroke-m", "5e-6", "--scatter", "0.05"], "--scatter", "plant"),
])  # fmt: skip
def test_an_ideal_plates_options_another_axis_or_the_plant_reads_are_refused(capsys, extra, option, words):
    """They were silently ignored: θ ran on --stroke-rad with --stroke-m given, x on --stroke-m
    with --stroke-rad given, and --scatter on the ideal plate printed ± 0."""
    argv = ["simulate", "--part", "300x300x50", "--ideal", "--frequency-hz", "100", "--flyback-s", "3.5e-4",
            "--periods", "2", *extra]  # fmt: skip
    err = refused(capsys, argv)
    assert err.startswith(f"feeder simulate: error: {option}:") and words in err


def test_a_scatter_meant_as_percent_is_refused(capsys):
    """--scatter 5 (meant as 5 %) drove a forward waveform's part backwards by 33 µm a period."""
    argv = ["simulate", "--part", "300x300x50", "--waveform", str(PAPER), "--periods", "2", "--scatter", "5"]
    err = refused(capsys, argv)
    assert err.startswith("feeder simulate: error: --scatter:") and "0.05 is 5 %" in err
