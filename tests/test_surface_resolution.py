"""Resolution of summit statistics: pixel noise's summit density, the Gaussian low-pass,
and the warning and --cutoff-wavelength of ``feeder surface``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from feeder.cli import main
from feeder.errors import InputError
from feeder.surface.parameters import load_surface
from feeder.surface.reading import HeightMap, read_height_map
from feeder.surface.statistics import low_pass, surface_statistics


def test_pure_pixel_noise_has_one_summit_in_nine_pixels() -> None:
    noise = np.random.default_rng(5).normal(size=(400, 400)) * 1e-9
    stats = surface_statistics(HeightMap(noise, (2e-9, 2e-9), "noise"))
    assert stats.noise_summit_fraction == pytest.approx(1.0, abs=0.03)


def test_low_pass_transmits_half_at_the_cutoff() -> None:
    pixel, n = 1e-9, 256
    x = np.arange(n) * pixel
    for wavelength, expected in ((32e-9, 0.5), (128e-9, 0.5 ** (1 / 16)), (8e-9, 0.5**16)):
        wave = np.sin(2 * math.pi * x / wavelength)[None, :] * np.ones((n, 1))
        out = low_pass(wave, (pixel, pixel), 32e-9)
        assert np.max(np.abs(out)) == pytest.approx(expected, rel=1e-9, abs=1e-12)


def test_cli_warns_about_noise_and_shows_the_cutoffs_effect(tmp_path: Path, capsys) -> None:
    rng = np.random.default_rng(6)
    smooth = low_pass(rng.normal(size=(256, 256)), (1.0, 1.0), 20.0) * 50.0  # nm
    np.save(tmp_path / "map.npy", smooth + rng.normal(size=smooth.shape) * 0.5)
    base = ["surface", str(tmp_path / "map.npy"), "--pixel-size", "2e-9", "--height-unit", "nm", "--json"]
    assert main(base) == 0
    noisy = json.loads(capsys.readouterr().out)
    assert noisy["noise_summit_fraction"] > 0.1 and "pixel noise" in noisy["warnings"][0]
    assert main([*base, "--cutoff-wavelength", "20e-9"]) == 0
    filtered = json.loads(capsys.readouterr().out)
    assert filtered["warnings"] == [] and filtered["cutoff_wavelength_m"] == 20e-9
    assert filtered["summit_density_per_m2"] < 0.2 * filtered["unfiltered"][0]["summit_density_per_m2"]
    assert filtered["mean_summit_radius_m"] > 1.5 * filtered["unfiltered"][0]["mean_summit_radius_m"]


def test_plain_map_needs_a_height_unit_and_nothing_is_written(tmp_path: Path, capsys) -> None:
    np.save(tmp_path / "map.npy", np.random.default_rng(0).normal(size=(64, 64)))  # meant in nm
    out = tmp_path / "s.toml"
    base = ["surface", str(tmp_path / "map.npy"), "--pixel-size", "2e-9", "--out", str(out)]
    assert main(base) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--height-unit: map.npy is a plain height map without units" in err
    assert not out.exists()
    with pytest.raises(InputError, match="--height-unit"):
        read_height_map(tmp_path / "map.npy", pixel_size_m=2e-9)
    assert main([*base, "--height-unit", "m"]) == 2  # nm read as metres: σ ≈ 1 m, R ≈ 1e-17 m
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1
    assert "map.npy: sigma_m: 0.9974 m is beyond 1 mm" in captured.err and "--height-unit" in captured.err
    assert not out.exists()
    assert main([*base, "--height-unit", "nm"]) == 0
    assert load_surface(out).sigma_m == pytest.approx(0.9974e-9, rel=1e-3)


def test_negative_pixel_size_reaches_the_range_check(tmp_path: Path, capsys) -> None:
    np.save(tmp_path / "map.npy", np.zeros((8, 8)))
    with pytest.raises(SystemExit) as usage:
        main(["surface", str(tmp_path / "map.npy"), "--pixel-size", "-2e-9", "--height-unit", "nm"])
    assert usage.value.code == 2
    assert "--pixel-size: must be from 1e-12 to 0.01, got '-2e-9'" in capsys.readouterr().err


AFM = Path(__file__).resolve().parents[1].parent / "shared" / "afm"


@pytest.mark.skipif(not AFM.is_dir(), reason=f"real AFM files not found at {AFM}")
def test_a_mean_radius_made_by_a_few_flat_summits_is_warned_about(capsys: pytest.CaptureFixture[str]) -> None:
    """spot_1-1000nm.ibw: 5 of 4578 summits make 19 % of the mean R (20.5 µm, 3.9× 1/(mean
    curvature)); the GW model takes the mean.  example_ps.tiff's summits are alike (1.24×)."""
    assert main(["surface", str(AFM / "spot_1-1000nm.ibw"), "--json"]) == 0
    spot = json.loads(capsys.readouterr().out)
    (tail,) = [w for w in spot["warnings"] if "nearly flat summits" in w]
    ratio = spot["mean_summit_radius_m"] / spot["radius_from_mean_curvature_m"]
    assert ratio > 3 and f"{ratio:.3g}×" in tail
    assert main(["surface", str(AFM / "example_ps.tiff"), "--json"]) == 0
    assert not [w for w in json.loads(capsys.readouterr().out)["warnings"] if "flat summits" in w]


def test_quantised_noise_whose_mean_radius_is_kilometres_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Integer heights (pm) of pure noise: flat summits gave R = 36.5 km and a breakaway of 2.3e7 g."""
    np.save(tmp_path / "ints.npy", (np.random.default_rng(0).normal(size=(256, 256)) * 100).astype(int))
    out = tmp_path / "s.toml"
    argv = [
        "surface",
        str(tmp_path / "ints.npy"),
        "--pixel-size",
        "1e-9",
        "--height-unit",
        "pm",
        "--out",
        str(out),
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "summit_radius_m" in err and "beyond 1 m" in err
    assert not out.exists()
