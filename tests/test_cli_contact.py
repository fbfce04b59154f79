"""``feeder contact``: JSON contract, the paper table, and one-line errors with exit code 2."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from feeder.cli import main
from feeder.paper import PAPER_ROWS
from feeder.surface.parameters import DEFAULT_SURFACE

KEYS = {
    "mass_kg",
    "weight_N",
    "nominal_area_m2",
    "separation_m",
    "real_area_m2",
    "contacts",
    "breakaway_force_N",
    "breakaway_force_band_N",
    "breakaway_accel_m_s2",
    "warnings",
}


def run_json(capsys: pytest.CaptureFixture[str], *args: str) -> dict:
    assert main(["contact", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_json_object_has_the_contract_keys(capsys: pytest.CaptureFixture[str]) -> None:
    data = run_json(capsys, "--part", "300x300x50")
    assert data.keys() >= KEYS
    lo, hi = data["breakaway_force_band_N"]
    assert lo < data["breakaway_force_N"] < hi
    assert data["breakaway_accel_m_s2"] == pytest.approx(data["breakaway_force_N"] / data["mass_kg"])
    assert data["real_area_m2"] == pytest.approx(4.9734e-17, rel=2e-3)


def test_the_smallest_part_gets_its_breakaway_without_the_placements_band(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A 1 µm part (the smallest side the CLI takes) rests on no summits the sampling can find:
    GW's figures stand, the band is missing, and a warning says why (it was exit 2)."""
    data = run_json(capsys, "--part", "1x1x1")
    assert data["breakaway_accel_m_s2"] == pytest.approx(111.1, rel=1e-3)
    assert data["real_area_band_m2"] is None
    assert any("no A_r band from resting placements" in w for w in data["warnings"])


@pytest.mark.parametrize(("part", "accel"), [("5000x5000x50", 105.25), ("100000x100000x10000", 95.49)])
def test_large_parts_get_gw_without_sampling_their_placements(capsys: pytest.CaptureFixture[str],
                                                              part: str, accel: float) -> None:  # fmt: skip
    """Parts beyond 500 contacts (a 5 mm part: 890; their placements' draw needed 2.2 GiB and more,
    exit 2 for sides the CLI takes) get GW's figures and say why the band is missing."""
    data = run_json(capsys, "--part", part)
    assert data["contacts"] > 500
    assert data["breakaway_accel_m_s2"] == pytest.approx(accel, rel=2e-3)  # 10 mm thick: more pressure
    assert data["real_area_band_m2"] is None
    assert any("contacts under this part, beyond the 500" in w for w in data["warnings"])


def test_decimal_part_and_tau_option(capsys: pytest.CaptureFixture[str]) -> None:
    data = run_json(capsys, "--part", "123.5x80x49.9", "--tau", "10e9")
    assert data["mass_kg"] == pytest.approx(2330 * 123.5e-6 * 80e-6 * 49.9e-6)
    assert data["breakaway_force_N"] == pytest.approx(10e9 * data["real_area_m2"])


def test_surface_file_is_used(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    shifted = replace(DEFAULT_SURFACE, mean_summit_height_m=DEFAULT_SURFACE.mean_summit_height_m + 10e-9)
    shifted.write_toml(path)
    default = run_json(capsys, "--part", "300x300x50")
    moved = run_json(capsys, "--part", "300x300x50", "--surface", str(path))
    assert moved["separation_m"] - default["separation_m"] == pytest.approx(10e-9, rel=1e-9)
    assert moved["real_area_m2"] == pytest.approx(default["real_area_m2"], rel=1e-9)


def test_table_covers_four_parts_on_two_supports(capsys: pytest.CaptureFixture[str]) -> None:
    data = run_json(capsys, "--table")
    assert {(r["part"], r["support"]) for r in data["rows"]} == {
        (p, s) for p in PAPER_ROWS for s in ("flat", "grooved")
    }
    flat = [r for r in data["rows"] if r["support"] == "flat"]
    assert all(abs(r["real_area_deviation"]) < 2e-3 for r in flat)
    assert main(["contact", "--table"]) == 0
    text = capsys.readouterr().out
    assert "300x300x50" in text and "warning:" in text and "0.76" in text


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (["--part", "300x300"], "--part"),
        (["--part=-1x2x3"], "--part"),
        (["--part", "-1x2x3"], "--part"),
        (["--part", "axbxc"], "--part"),
        (["--part", "0x300x50"], "--part"),
        (["--part", "300x300x50", "--support", "sideways"], "--support"),
        (["--part", "300x300x50", "--surface", "/nonexistent/surface.toml"], "surface.toml"),
        (["--part", "300x300x50", "--tau", "-1"], "--tau"),
        ([], "--part"),
    ],
)
def test_bad_input_is_one_line_exit_2(
    capsys: pytest.CaptureFixture[str], args: list[str], field: str
) -> None:
    try:
        code = main(["contact", *args])
    except SystemExit as exit_:  # argparse's own usage errors
        code = int(exit_.code or 0)
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and field in err and "Traceback" not in err


@pytest.mark.parametrize(
    ("text", "field"),
    [
        (
            "[surface]\nsigma_m = -0.482e-9\nsummit_radius_m = 55e-9\n"
            "summit_density_per_m2 = 124.1e12\nmean_summit_height_m = 32.227e-9\n",
            "sigma_m",
        ),
        ("[surface]\nsigma_m = 0.482e-9\n", "summit_radius_m"),
        ("[surface\nsigma_m = 1\n", "not valid TOML"),
        ("[surface]\nsigma_m = 'big'\n", "sigma_m"),
        ("[surface]\nsigmaa_m = 1e-9\n", "sigmaa_m"),
    ],
)
def test_malformed_surface_file(tmp_path: Path, text: str, field: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    proc = subprocess.run(
        [sys.executable, "-m", "feeder", "contact", "--part", "300x300x50", "--surface", str(path)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and field in proc.stderr and "bad.toml" in proc.stderr
    assert proc.stdout == ""


@pytest.mark.parametrize(
    ("text", "field"),
    [  # heights read in the wrong unit: positive and finite, but no surface
        ("sigma_m = 0.98\nsummit_radius_m = 8.7e-18\nsummit_density_per_m2 = 2.9e16\n"
         "mean_summit_height_m = 1.48\n", "[surface].sigma_m"),
        ("sigma_m = 0.482e-9\nsummit_radius_m = 8.7e-18\nsummit_density_per_m2 = 124.1e12\n"
         "mean_summit_height_m = 32.227e-9\n", "[surface].summit_radius_m"),
        ("sigma_m = 0.482e-9\nsummit_radius_m = 55e-9\nsummit_density_per_m2 = 124.1e12\n"
         "mean_summit_height_m = -2e-3\n", "[surface].mean_summit_height_m"),
        ("sigma_m = 0.482e-9\nsummit_radius_m = 55e-9\nsummit_density_per_m2 = 1e24\n"
         "mean_summit_height_m = 32.227e-9\n", "[surface].summit_density_per_m2"),
    ],
)  # fmt: skip
def test_impossible_surface_statistics_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, field: str
) -> None:
    path = tmp_path / "unit_slip.toml"
    path.write_text("[surface]\n" + text)
    assert main(["contact", "--part", "300x300x50", "--surface", str(path)]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1
    assert f"unit_slip.toml: {field}" in captured.err and "wrong unit" in captured.err


def test_material_lines_are_readable_and_the_shear_warning_names_the_material(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["contact", "--part", "300x300x50", "--material", "pmma", "--placements", "0"]) == 0
    out = capsys.readouterr().out
    assert "effective_modulus_pa" not in out and "material_adhesion_work_j_m2" not in out
    lines = out.splitlines()
    assert "  E*                1.738 GPa" in lines
    assert "  hardness H        0.25 GPa (the softer body's)" in lines
    assert any(line.startswith("  library w         0.082 J/m²") for line in lines)
    shear = [line for line in lines if "shear" in line and line.startswith("  warning: τ")]
    assert len(shear) == 1 and "silicon's ideal" not in shear[0]
    # 22.18 GPa against PMMA's k = H/(3√3) = 0.048 GPa
    assert "pmma's shear yield strength" in shear[0] and "461×" in shear[0] and "pmma on pmma" in shear[0]


def test_shear_warning_compares_with_the_softer_body() -> None:
    from feeder.contact.breakaway import contact as contact_of
    from feeder.parts import Part

    part = Part.parse("300x300x50")
    steel = replace(
        DEFAULT_SURFACE, support_youngs_modulus_pa=210e9, support_poisson_ratio=0.3, hardness_pa=7.4e9
    )
    # 5 GPa: below silicon's ideal shear strength, above steel's k = 7.4/(3√3) = 1.42 GPa
    on_silicon = contact_of(part, surface=DEFAULT_SURFACE, tau_pa=5e9).warnings
    on_steel = contact_of(part, surface=steel, tau_pa=5e9).warnings
    assert not any("shear" in w for w in on_silicon)
    (warning,) = [w for w in on_steel if "shear" in w]
    assert "steel's shear yield strength" in warning and "silicon on steel" in warning
    assert not any("shear" in w for w in contact_of(part, surface=steel, tau_pa=1e9).warnings)
    silicon = contact_of(part, surface=DEFAULT_SURFACE).warnings  # the paper's 22 GPa on silicon
    assert any("exceeds silicon's ideal shear strength" in w for w in silicon)


@pytest.mark.parametrize(
    ("option", "value"), [("--part", "300x300x50"), ("--support", "grooved"), ("--density", "2000")]
)
def test_table_refuses_the_options_it_would_ignore(
    capsys: pytest.CaptureFixture[str], option: str, value: str
) -> None:
    assert main(["contact", "--table", "--placements", "0", option, value]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1
    assert f"{option}: not with --table" in captured.err


@pytest.mark.parametrize("json_flag", [["--json"], []])
def test_a_closed_stdout_exits_quietly(json_flag: list[str]) -> None:
    """``feeder contact --table --json | head -c 400``: the reader leaves before the output."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "feeder", "contact", "--table", "--placements", "0", *json_flag],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # before the table is computed and written
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141
    assert err == ""


def test_the_papers_tau_on_another_surface_says_it_is_assumed(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """It read "fitted to the paper's forces" next to a 9.8 µN breakaway on an AFM scan's surface
    (the paper measured 0.94 µN): τ was only fitted on the paper's own surface."""
    same, other = tmp_path / "same.toml", tmp_path / "other.toml"
    DEFAULT_SURFACE.write_toml(same)
    replace(DEFAULT_SURFACE, summit_radius_m=4 * DEFAULT_SURFACE.summit_radius_m).write_toml(other)
    assert run_json(capsys, "--part", "300x300x50", "--surface", str(same))["tau_source"].startswith("fitted")
    source = run_json(capsys, "--part", "300x300x50", "--surface", str(other))["tau_source"]
    assert "assumed for this surface" in source and "--tau" in source
