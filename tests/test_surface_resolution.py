"""Resolution of summit statistics: pixel noise's summit density, the Gaussian low-pass,
and the warning and --cutoff-wavelength of ``feeder surface``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from feeder.cli import main
from feeder.surface.reading import HeightMap
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
