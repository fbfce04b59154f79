"""What the physics commands say beside their results: ``feeder surface`` warns of scale options an
instrument file ignores, ``feeder contact --json`` always reports E* and H, and ``feeder simulate
--ideal --waveform`` warns when the amplifier cannot follow the command's flyback."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_physics_cli_inputs import HAND_FLYBACK_S, WAVEFORM, Capture, run

AFM = Path(__file__).resolve().parents[1].parent / "shared" / "afm"
needs_afm = pytest.mark.skipif(
    not AFM.is_dir() or importlib.util.find_spec("SurfaceTopography") is None,
    reason=f"real AFM files ({AFM}) or the afm extra not available",
)


# ---------------------------------------------------------------- surface: ignored scale options


@needs_afm
def test_surface_warns_that_an_instrument_file_ignores_pixel_size_and_height_unit(capsys: Capture) -> None:
    scan = str(AFM / "di-5.di")
    code, out, err = run(capsys, "surface", scan, "--json")
    assert code == 0 and err == ""
    plain = json.loads(out)
    # was: both options silently ignored, stderr empty, the same report
    code, out, err = run(capsys, "surface", scan, "--pixel-size", "1e-9", "--height-unit", "m", "--json")
    assert code == 0
    given = json.loads(out)
    assert given["pixel_size_m"] == plain["pixel_size_m"] and given["sq_m"] == plain["sq_m"]
    assert given["pixel_size_m"][0] == pytest.approx(1e-6 / 512, rel=1e-9)  # the file's, not 1e-9
    lines = err.splitlines()
    assert len(lines) == 2 and all(line.startswith("feeder surface: warning: ") for line in lines)
    for line, flag in zip(lines, ("--pixel-size", "--height-unit"), strict=True):
        assert f"{flag} is ignored for {scan}: the file states its own pixel size and height unit" in line
    ignored = [w for w in given["warnings"] if "is ignored for" in w]
    assert [f"feeder surface: warning: {w}" for w in ignored] == lines
    assert [w for w in given["warnings"] if w not in ignored] == plain["warnings"]


@needs_afm
def test_surface_names_only_the_instrument_file_beside_a_plain_map(capsys: Capture, tmp_path: Path) -> None:
    heights = np.random.default_rng(1).normal(0.0, 0.5, (64, 64))
    plain = tmp_path / "map.npy"
    np.save(plain, heights)
    instrument = AFM / "stp-1.stp"
    code, out, err = run(capsys, "surface", str(plain), str(instrument), "--pixel-size", "2e-9",
                         "--height-unit", "nm")  # fmt: skip
    assert code == 0, err
    lines = err.splitlines()
    assert len(lines) == 2 and all(f"is ignored for {instrument}:" in line for line in lines)
    assert "--pixel-size" in lines[0] and "--height-unit" in lines[1] and str(plain) not in err
    assert "is ignored" not in out  # the text report's own warnings stay on stdout, these on stderr
    code, _, err = run(capsys, "surface", str(plain), "--pixel-size", "2e-9", "--height-unit", "nm")
    assert code == 0 and err == ""  # a plain map reads both options


@needs_afm
def test_surface_bad_input_after_reading_stays_one_line(capsys: Capture) -> None:
    scan = str(AFM / "stp-1.stp")
    code, out, err = run(capsys, "surface", scan, scan, "--bem", "--pixel-size", "1e-9")
    assert code == 2 and out == "" and len(err.splitlines()) == 1 and "--bem" in err


# ---------------------------------------------------------------- contact: E* and H always


def _contact(capsys: Capture, *args: str) -> dict[str, Any]:
    code, out, err = run(capsys, "contact", "--part", "300x300x50", "--placements", "0", *args, "--json")
    assert code == 0, err
    return json.loads(out)


def test_contact_json_always_reports_the_effective_modulus_and_hardness(
    capsys: Capture, tmp_path: Path
) -> None:
    # was: effective_modulus_pa and hardness_pa only with --material (KeyError here)
    embedded = _contact(capsys)
    assert embedded["effective_modulus_pa"] == pytest.approx(169e9 / (2 * (1 - 0.28**2)), rel=1e-12)
    assert embedded["hardness_pa"] == 12e9  # silicon's, the plasticity index's H
    assert "part_material" not in embedded  # the material keys still come with --material only
    surface = tmp_path / "glassy.toml"
    surface.write_text(
        "[surface]\nsigma_m = 0.482e-9\nsummit_radius_m = 55.0e-9\nsummit_density_per_m2 = 124.1e12\n"
        "mean_summit_height_m = 32.227e-9\n[material]\nyoungs_modulus_pa = 70e9\npoisson_ratio = 0.2\n"
        "hardness_pa = 5e9\n"
    )
    filed = _contact(capsys, "--surface", str(surface))
    assert filed["effective_modulus_pa"] == pytest.approx(70e9 / (2 * (1 - 0.2**2)), rel=1e-12)
    assert filed["hardness_pa"] == 5e9
    surface.write_text(surface.read_text().replace("hardness_pa = 5e9\n", ""))
    assert _contact(capsys, "--surface", str(surface))["hardness_pa"] == 12e9  # the file's default H
    sapphire = _contact(capsys, "--material", "sapphire")  # as before with --material
    assert sapphire["effective_modulus_pa"] == pytest.approx(345e9 / (2 * (1 - 0.29**2)), rel=1e-12)
    assert sapphire["hardness_pa"] == 22e9 and sapphire["part_material"] == "sapphire"


def test_contact_table_json_reports_the_effective_modulus_and_hardness(capsys: Capture) -> None:
    code, out, _ = run(capsys, "contact", "--table", "--placements", "0", "--json")
    table = json.loads(out)
    assert code == 0 and len(table["rows"]) == 8
    assert table["effective_modulus_pa"] == pytest.approx(169e9 / (2 * (1 - 0.28**2)), rel=1e-12)
    assert table["hardness_pa"] == 12e9


# ---------------------------------------------------------------- simulate --ideal: the flyback


HAND_FLYBACK_US = 1e6 * HAND_FLYBACK_S  # the amplifier's flyback (test_physics_cli_inputs)


def _simulate(capsys: Capture, path: Path, *args: str) -> tuple[int | str | None, str, str]:
    return run(capsys, "simulate", "--part", "500x500x50", "--ideal", "--waveform", str(path),
               "--periods", "3", *args)  # fmt: skip


@pytest.mark.parametrize("shape", ["linear", "half-cosine"])
def test_ideal_plate_warns_when_the_amplifier_cannot_follow_the_flyback(
    capsys: Capture, tmp_path: Path, shape: str
) -> None:
    path = tmp_path / "fast.toml"
    path.write_text(WAVEFORM.format(shape=shape, flyback_s="1e-5"))
    assert round(HAND_FLYBACK_US, 1) == 350.9
    # was: no warning; the ideal plate silently flew back in the command's 10 µs
    code, out, err = _simulate(capsys, path, "--json")
    assert code == 0
    result = json.loads(out)
    assert result["flyback_s"] == 1e-5 and result["model"] == "ideal"  # the ideal plate as designed
    (warning,) = [w for w in result["warnings"] if "cannot follow" in w]
    assert warning.startswith(f"{path}: the amplifier cannot follow the command's 10 µs {shape} flyback")
    assert "flies back in 350.9 µs, current-limited, over 193 V of 200 V" in warning
    assert "without --ideal gives what the plate does" in warning
    assert err == ""
    code, out, err = _simulate(capsys, path)
    assert code == 0 and err == ""  # text: one warning line, as every simulate warning (docs/plant.md)
    assert [line for line in out.splitlines() if "cannot follow" in line] == [f"  warning: {warning}"]


def test_ideal_theta_plate_warns_too(capsys: Capture, tmp_path: Path) -> None:
    path = tmp_path / "fast.toml"
    path.write_text(WAVEFORM.format(shape="linear", flyback_s="1e-5"))
    code, out, err = _simulate(capsys, path, "--axis", "theta", "--json")
    assert code == 0 and any("cannot follow" in w for w in json.loads(out)["warnings"])
    assert err == "" and "350.9 µs" in next(w for w in json.loads(out)["warnings"] if "cannot follow" in w)


@pytest.mark.parametrize(
    ("shape", "flyback_s"),
    [("linear", "1e-3"), ("half-cosine", "1e-3"), ("current-limited", "1e-5")],
)
def test_no_warning_for_a_flyback_the_amplifier_makes(
    capsys: Capture, tmp_path: Path, shape: str, flyback_s: str
) -> None:
    # 1 ms: 2e5 V/s linear, 3.1e5 V/s half-cosine peak, both below 5.5e5 V/s; current-limited: the
    # ideal plate already takes the amplifier's flyback
    path = tmp_path / "followed.toml"
    path.write_text(WAVEFORM.format(shape=shape, flyback_s=flyback_s))
    code, out, err = _simulate(capsys, path, "--json")
    assert code == 0 and err == ""
    assert not any("cannot follow" in w for w in json.loads(out)["warnings"])
    plant = ("simulate", "--part", "500x500x50", "--waveform", str(path), "--periods", "3", "--json")
    code, out, err = run(capsys, *plant)
    assert code == 0 and "cannot follow" not in out + err  # the plant makes the amplifier's flyback
