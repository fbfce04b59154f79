"""GW against ContactMechanics' BEM: the wrapper against Hertz, the CLI contract, the shared scans (slow)."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ContactMechanics")

from feeder.cli import main
from feeder.contact.bem import RESOLVED_PIXELS, bem_contact_fraction


def test_bem_of_a_paraboloid_is_hertz() -> None:
    # one paraboloid cap R on a periodic cell, pressed with force P: πa², a = (3PR/4E*)^(1/3)
    n, cell, radius, modulus = 128, 2e-6, 5e-6, 91.69e9
    x = (np.arange(n) - n / 2 + 0.5) * cell / n
    heights = -(x[:, None] ** 2 + x[None, :] ** 2) / (2 * radius)
    force = 1e-3  # a ≈ 22 px: 1528 contact pixels
    fraction, pixels = bem_contact_fraction(heights, (cell / n, cell / n), modulus, force / cell**2)
    a = (3 * force * radius / (4 * modulus)) ** (1 / 3)
    assert pixels > RESOLVED_PIXELS
    assert fraction * cell**2 == pytest.approx(math.pi * a * a, rel=0.01)  # observed 3e-4; 7 % at a ≈ 5 px


def test_surface_bem_json_on_a_plain_map(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(3)
    spectrum = np.fft.fft2(rng.normal(size=(64, 64)))
    k = np.hypot(*np.meshgrid(np.fft.fftfreq(64), np.fft.fftfreq(64)))
    heights = np.real(np.fft.ifft2(spectrum * (k < 0.12))) * 2.0  # smooth on ~8 px
    path = tmp_path / "map.npy"
    np.save(path, heights)
    assert main(["surface", str(path), "--pixel-size", "5e-9", "--height-unit", "nm", "--bem", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["bem_nominal_pressure_pa"] == pytest.approx(2330 * 9.81 * 50e-6, rel=1e-12)
    sweep = data["bem_sweep"]
    assert sweep[0]["pressure_pa"] == data["bem_nominal_pressure_pa"]
    assert data["bem_gw_ratio"] == pytest.approx(
        data["bem_real_area_fraction"] / data["gw_real_area_fraction"]
    )
    fractions = [p["bem_real_area_fraction"] for p in sweep]
    assert fractions == sorted(fractions)  # more pressure, more contact
    assert not data["bem_resolved"] and data["bem_contact_pixels"] == 1  # ~1 Pa on 0.1 µm²: one pixel
    assert any("one pixel's, an upper bound" in w for w in data["warnings"])
    assert main(["surface", str(path), str(path), "--pixel-size", "5e-9", "--bem"]) == 2


@pytest.mark.slow
@pytest.mark.parametrize("scan", ["example_ps.tiff", "di-5.di", "nid-1.nid", "stp-1.stp"])
def test_shared_scans_under_a_minute(scan: str, shared_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    start = time.perf_counter()
    assert main(["surface", str(shared_dir / "afm" / scan), "--bem", "--json"]) == 0
    assert time.perf_counter() - start < 60
    data = json.loads(capsys.readouterr().out)
    resolved = [p for p in data["bem_sweep"] if p["bem_resolved"]]
    assert resolved
    assert 0.3 < resolved[-1]["bem_gw_ratio"] < 2.5  # the audit's 0.35–2.3 band, where BEM resolves
