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
