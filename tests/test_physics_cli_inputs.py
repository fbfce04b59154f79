"""The physics commands at their edges: the grooved/flat ratio fit's bad input and refusals, the
flyback ``waveform show`` reports (the amplifier's, not the command's), material constants in a
surface file, the ``closed_form_step_m`` key, τ's wording and its units on the command line."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from feeder.cli import arguments, build_parser, main
from feeder.contact.adhesion_fit import RATIO_BAND, check_ratios, default_band
from feeder.errors import InputError
from feeder.surface import parameters
from feeder.surface.parameters import DEFAULT_SURFACE, load_surface

Capture = pytest.CaptureFixture[str]


def run(capsys: Capture, *argv: str) -> tuple[int | str | None, str, str]:
    """``feeder ARGV`` in-process: (exit code, stdout, stderr); argparse's exit is caught."""
    try:
        code: int | str | None = main(list(argv))
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out, err


def assert_bad_input(ran: tuple[int | str | None, str, str], *named: str) -> None:
    """Exit 2, nothing on stdout, one line on stderr naming each of ``named``."""
    code, out, err = ran
    assert code == 2, (code, out, err)
    assert out == "" and len(err.strip().splitlines()) == 1, err
    for name in named:
        assert name in err, (name, err)


# ---------------------------------------------------------------- D1: adhesion fit


@pytest.mark.parametrize("ratio", ["1.5", "1.0001", "0", "-0.2"])
def test_a_ratio_that_is_no_area_ratio_is_bad_input(capsys: Capture, ratio: str) -> None:
    # was: exit 0 and "adhesion_work_j_m2": null for 1.5
    assert_bad_input(run(capsys, "adhesion", "fit", f"--ratio={ratio}", "--json"), "--ratio")


@pytest.mark.parametrize("band", [("0.78", "0.70"), ("0.2", "0.3"), ("0.7", "1.2"), ("0.74", "0.74")])
def test_a_band_reversed_or_without_the_ratio_is_bad_input(capsys: Capture, band: tuple[str, str]) -> None:
    # was: accepted (0.78 0.70 gave a w band anyway; 0.2 0.3 a band for another ratio)
    assert_bad_input(run(capsys, "adhesion", "fit", "--ratio-band", *band, "--json"), "--ratio-band")


def test_a_ratio_the_model_does_not_reach_is_refused(capsys: Capture) -> None:
    # was: exit 0 with "adhesion_work_j_m2": null and the reason in "explanation"
    code, out, err = run(capsys, "adhesion", "fit", "--ratio", "0.4", "--json")
    assert code == 1 and out == ""
    assert err.strip().splitlines() == [
        "feeder adhesion: refused: no w in 0.0001–1 J/m² gives the ratio 0.4: the model spans 0.500–0.989"
    ]


def test_the_library_checks_target_and_band() -> None:
    with pytest.raises(InputError, match=r"^target: "):
        check_ratios(1.5, RATIO_BAND)
    with pytest.raises(InputError, match=r"^band: "):
        check_ratios(0.74, (0.78, 0.70))
    with pytest.raises(InputError, match=r"^band: .*does not contain"):
        check_ratios(0.74, (0.2, 0.3))
    check_ratios(0.74, RATIO_BAND)
    # another target without a band gets the measured half-width around it, within (0, 1]
    assert default_band(0.74) == RATIO_BAND
    assert default_band(0.6) == pytest.approx((0.56, 0.64))
    assert default_band(0.99) == pytest.approx((0.95, 1.0))
    assert default_band(0.02) == pytest.approx((0.01, 0.06))


# ---------------------------------------------------------------- D2: waveform show


WAVEFORM = """[waveform]
shape = "sawtooth"
frequency_hz = 100.0
amplitude_vpp = 200.0
offset_v = 0.0
flyback_shape = "{shape}"
flyback_s = {flyback_s}
direction = "forward"
"""

# the default amplifier into the default 1 µF stack: min(slew, I/C) = 5.5e5 V/s; 0.07 µm/V
HAND_FLYBACK_S = 200 / (5.5e5 + 200 * 100)  # 0.351 ms: the output meets the rising command
HAND_SWING_V = 200 * (1 - HAND_FLYBACK_S * 100)  # 193.0 V
HAND_STROKE_M = 0.07e-6 * HAND_SWING_V  # 13.51 µm


@pytest.mark.parametrize("shape", ["linear", "half-cosine"])
def test_show_reports_the_current_limited_flyback_the_amplifier_makes(
    capsys: Capture, tmp_path: Path, shape: str
) -> None:
    path = tmp_path / "fast.toml"
    path.write_text(WAVEFORM.format(shape=shape, flyback_s="1e-5"))
    code, out, _ = run(capsys, "waveform", "show", str(path), "--json")
    assert code == 0
    shown = json.loads(out)
    # was: flyback_s 1e-05, output_swing_v 200.0, stroke_m 1.4e-05 (the command's)
    assert round(HAND_FLYBACK_S, 6) == 0.351e-3 and round(HAND_SWING_V, 1) == 193.0
    assert shown["flyback_s"] == pytest.approx(HAND_FLYBACK_S, rel=1e-9)
    assert shown["rise_s"] == pytest.approx(0.01 - HAND_FLYBACK_S, rel=1e-9)
    assert shown["output_swing_v"] == pytest.approx(HAND_SWING_V, rel=1e-9)
    assert shown["stroke_m"] == pytest.approx(13.51e-6, abs=0.005e-6)
    assert shown["stroke_m"] == pytest.approx(HAND_STROKE_M, rel=1e-9)
    assert shown["flyback_current_limited"] is True and shown["flyback_shape"] == shape
    assert shown["command_flyback_s"] == 1e-5 and shown["command_stroke_m"] == pytest.approx(14e-6)
    assert any("current limit sets the flyback" in w for w in shown["warnings"])
    code, out, _ = run(capsys, "waveform", "show", str(path))
    lines = dict(line.split(None, 1) for line in out.splitlines() if not line.startswith("warning"))
    printed = (lines["flyback_s"], lines["output_swing_v"], lines["stroke_m"])
    assert printed == ("0.000350877", "192.982", "1.35088e-05")


def test_show_keeps_a_flyback_the_amplifier_follows(capsys: Capture, tmp_path: Path) -> None:
    path = tmp_path / "slow.toml"
    path.write_text(WAVEFORM.format(shape="linear", flyback_s="1e-3"))  # 2e5 V/s < 5.5e5 V/s
    code, out, _ = run(capsys, "waveform", "show", str(path), "--json")
    shown = json.loads(out)
    assert code == 0 and shown["flyback_current_limited"] is False and shown["warnings"] == []
    assert (shown["flyback_s"], shown["output_swing_v"]) == (1e-3, 200.0)
    assert shown["stroke_m"] == pytest.approx(14e-6, rel=1e-12)


# ---------------------------------------------------------------- D3, D4: surface file's material


SURFACE = """[surface]
sigma_m = 0.482e-9
summit_radius_m = 55.0e-9
summit_density_per_m2 = 124.1e12
mean_summit_height_m = 32.227e-9
[material]
poisson_ratio = 0.28
{material}
"""


@pytest.mark.parametrize(
    ("material", "field"),
    [
        ("youngs_modulus_pa = 169", "[material].youngs_modulus_pa"),  # GPa as a bare number
        ("youngs_modulus_pa = 1e14", "[material].youngs_modulus_pa"),
        ("support_youngs_modulus_pa = 345", "[material].support_youngs_modulus_pa"),
        ("adhesion_work_j_m2 = 1e3", "[material].adhesion_work_j_m2"),
        ("adhesion_work_j_m2 = 1e-8", "[material].adhesion_work_j_m2"),
    ],
)
def test_implausible_material_constants_name_their_field(
    capsys: Capture, tmp_path: Path, material: str, field: str
) -> None:
    # was: "--part: the surface cannot carry this part ..." (E = 169 Pa) and "load" with a
    # negative capacity (w = 1e3 J/m²); w = 1e-8 was taken though --adhesion-work refuses it
    path = tmp_path / "surface.toml"
    path.write_text(SURFACE.format(material=material))
    ran = run(capsys, "contact", "--part", "300x300x50", "--surface", str(path), "--placements", "0")
    assert_bad_input(ran, f"{path}: {field}")
    assert "--part" not in ran[2] and "load" not in ran[2]
    with pytest.raises(InputError, match=re.escape(field)):
        load_surface(path)


@pytest.mark.parametrize(
    "material",
    ["youngs_modulus_pa = 3e9", "youngs_modulus_pa = 1.05e12", "adhesion_work_j_m2 = 10.0",
     "adhesion_work_j_m2 = 0.0", "support_youngs_modulus_pa = 345e9"],
)  # fmt: skip
def test_the_materials_of_the_library_and_the_cli_range_are_accepted(tmp_path: Path, material: str) -> None:
    path = tmp_path / "surface.toml"
    path.write_text(SURFACE.format(material=material))
    load_surface(path)


def test_the_adhesion_work_range_is_defined_once() -> None:
    assert arguments.ADHESION_WORK_RANGE_J_M2 is parameters.ADHESION_WORK_RANGE_J_M2 == (1e-6, 10.0)
    low, high = parameters.YOUNGS_MODULUS_RANGE_PA
    assert low <= DEFAULT_SURFACE.youngs_modulus_pa <= high


# ---------------------------------------------------------------- simulate, contact, --tau


IDEAL = ["simulate", "--part", "300x300x50", "--ideal", "--stroke-m", "5e-6", "--frequency-hz", "100",
         "--flyback-s", "1e-4", "--periods", "3", "--json"]  # fmt: skip


def test_closed_form_step_is_null_without_a_closed_form(capsys: Capture) -> None:
    code, out, _ = run(capsys, *IDEAL, "--flyback-shape", "half-cosine")
    assert code == 0
    assert json.loads(out)["closed_form_step_m"] is None  # was: the key was missing
    code, out, _ = run(capsys, *IDEAL, "--flyback-shape", "linear")
    assert json.loads(out)["closed_form_step_m"] == pytest.approx(4.20849e-6, rel=1e-5)
    code, out, _ = run(capsys, *IDEAL[:-1], "--flyback-shape", "half-cosine")  # text: no "closed form"
    assert code == 0 and "closed form" not in out


def test_contact_says_where_a_given_tau_comes_from_once(capsys: Capture) -> None:
    code, out, _ = run(capsys, "contact", "--part", "300x300x50", "--tau", "2e10", "--placements", "0")
    assert code == 0 and "(given (" not in out  # was: "(given (fitted with w = 0 J/m²))"
    assert "20 ± 2.84 GPa, given (fitted with w = 0 J/m²)" in out


UNITS = [("22GPa", 22e9), ("22.18 GPa", 22.18e9), ("300kPa", 3e5), ("2MPa", 2e6), ("2.2e10Pa", 2.2e10),
         ("2.2e10", 2.2e10)]  # fmt: skip


@pytest.mark.parametrize(("text", "pa"), UNITS)
def test_tau_takes_pressure_units(capsys: Capture, text: str, pa: float) -> None:
    # was: "not a number: '22GPa'"
    argv = ["contact", "--part", "300x300x50", "--tau", text, "--placements", "0", "--json"]
    code, out, err = run(capsys, *argv)
    assert code == 0 and err == ""
    assert json.loads(out)["tau_pa"] == pytest.approx(pa, rel=1e-12)


def test_every_command_with_tau_takes_the_units(tmp_path: Path) -> None:
    commands = {
        "contact": ["contact", "--part", "300x300x50"],
        "plan": ["plan", "--part", "300x300x50", "--distance-m", "1e-4"],
        "simulate": ["simulate", "--part", "500x500x50", "--ideal"],
        "waveform": ["waveform", "design", "--part", "500x500x50", "--out", str(tmp_path / "d.toml")],
    }
    for name, argv in commands.items():
        args = build_parser([name]).parse_args([*argv, "--tau", "22GPa"])
        assert args.tau == 22e9, name
    args = build_parser(["plan"]).parse_args([*commands["plan"], "--tau", "20GPa", "--tau-band", "3GPa"])
    assert (args.tau, args.tau_band) == (20e9, 3e9)


def test_a_tau_below_a_kilopascal_is_warned_of_on_stderr(capsys: Capture) -> None:
    # was: --tau 22.18 silently gave a_break ≈ 1e-7 m/s²
    code, out, err = run(capsys, "contact", "--part", "300x300x50", "--tau", "22.18", "--placements", "0",
                         "--json")  # fmt: skip
    assert code == 0 and json.loads(out)["tau_pa"] == 22.18
    assert err.startswith("feeder contact: warning: --tau 22.18 Pa is below 1000 Pa") and "22GPa" in err
    code, out, err = run(capsys, "contact", "--part", "300x300x50", "--tau", "2kPa", "--placements", "0")
    assert code == 0 and err == ""


def test_a_low_tau_keeps_a_bad_input_error_one_line(capsys: Capture) -> None:
    ran = run(capsys, "plan", "--part", "300x300x50", "--distance-m", "1e-4", "--tau", "20")
    assert_bad_input(ran, "note: --tau 20 Pa is below 1000 Pa")
    ran = run(capsys, "contact", "--part", "300x300x50", "--tau", "20", "--placements", "-1")
    assert_bad_input(ran, "--placements")  # refused while parsing: no warning line before it
    part = ["contact", "--part", "300x300x50"]
    assert_bad_input(run(capsys, *part, "--tau", "-1e9"), "--tau: must be a positive")
    assert_bad_input(run(capsys, *part, "--tau", "22gpa"), "--tau", "GPa")
