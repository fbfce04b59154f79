"""Real AFM files (../shared/afm): reading in metres, Sq against SurfaceTopography's own
detrend + RMS, broken files as one-line errors, and `feeder surface` → `feeder contact`."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from feeder.cli import main
from feeder.errors import InputError
from feeder.surface.parameters import implausible, load_surface
from feeder.surface.reading import read_height_map
from feeder.surface.statistics import surface_statistics

AFM = Path(__file__).resolve().parents[1].parent / "shared" / "afm"
pytestmark = pytest.mark.skipif(not AFM.is_dir(), reason=f"real AFM files not found at {AFM}")

# file: (grid points, scan size in m) as the folder's README states them
READABLE = {
    "di-5.di": (512, 1e-6),
    "di-1.di": (512, 0.5e-6),
    "spot_1-1000nm.ibw": (256, 20e-6),
    "nid-1.nid": (256, 20e-6),
    "example_ps.tiff": (512, 1e-6),
    "stp-1.stp": (256, 0.6e-6),
}
BROKEN = ("di_corrupted.di", "nonsense_txt_file.txt", "wrongnpyfile.npy")


def test_every_file_in_the_folder_is_covered() -> None:
    names = {p.name for p in AFM.iterdir() if p.name != "README.md"}
    assert names == set(READABLE) | set(BROKEN)


@pytest.mark.parametrize("name", sorted(READABLE))
def test_readable_file_sq_matches_surface_topography(name: str) -> None:
    from SurfaceTopography import open_topography

    height_map = read_height_map(AFM / name)
    points, size = READABLE[name]
    assert height_map.heights_m.shape == (points, points)
    assert height_map.scan_size_m[0] == pytest.approx(size, rel=0.01)
    stats = surface_statistics(height_map)
    # independent: the package's own plane detrend and RMS height, converted to metres
    topography = (
        open_topography(str(AFM / name))
        .topography(channel_index=_channel_index(AFM / name, height_map.channel))
        .to_unit("m")
    )
    reference = topography.detrend(detrend_mode="height").rms_height_from_area()
    assert stats.sq_m == pytest.approx(reference, rel=0.01)
    assert 1e-10 < stats.sq_m < 1e-6  # nanometre-scale roughness: units converted to metres
    assert stats.summit_count > 100
    assert stats.summit_density_per_m2 == pytest.approx(
        stats.summit_count / ((points - 2) ** 2 * np.prod(height_map.pixel_size_m))
    )
    assert stats.summit_height_std_m > 0 and stats.mean_summit_radius_m > 0


def _channel_index(path: Path, name: str) -> int:
    from SurfaceTopography import open_topography

    return next(c.index for c in open_topography(str(path)).channels if c.name == name)


def test_height_channel_is_chosen_and_named_channels_work() -> None:
    assert read_height_map(AFM / "spot_1-1000nm.ibw").channel == "HeightTrace"
    retrace = read_height_map(AFM / "spot_1-1000nm.ibw", channel="HeightRetrace")
    assert retrace.channel == "HeightRetrace"
    with pytest.raises(InputError, match="not a height map"):
        read_height_map(AFM / "di-1.di", channel="Phase")  # unit degrees, not a length
    for other in ("AmplitudeTrace", "PhaseRetrace", "NapPotentialTrace"):  # the .ibw says metres for each
        with pytest.raises(InputError, match=f"channel '{other}' of spot_1-1000nm.ibw is not a height map"):
            read_height_map(AFM / "spot_1-1000nm.ibw", channel=other)
    with pytest.raises(InputError, match="no channel"):
        read_height_map(AFM / "di-5.di", channel="Nope")
    # di-1.di has two channels named Height (Sq 9.844 and 9.967 nm): the name picked channel 0
    with pytest.raises(InputError, match=r"2 channels named 'Height' \(indices 0, 1\): give the index"):
        read_height_map(AFM / "di-1.di", channel="Height")
    first, second = (read_height_map(AFM / "di-1.di", channel=k) for k in ("0", "1"))
    assert first.channel == second.channel == "Height" and not np.array_equal(
        first.heights_m, second.heights_m
    )


@pytest.mark.parametrize("name", BROKEN)
def test_broken_file_is_an_input_error_naming_it(name: str) -> None:
    with pytest.raises(InputError) as caught:
        read_height_map(AFM / name, pixel_size_m=1e-9)
    assert name in str(caught.value) and "\n" not in str(caught.value)


@pytest.mark.parametrize("name", BROKEN)
def test_cli_broken_file_exits_2_with_one_line(name: str, tmp_path: Path, capsys) -> None:
    out = tmp_path / "s.toml"
    code = main(["surface", str(AFM / name), "--pixel-size", "1e-9", "--out", str(out), "--json"])
    captured = capsys.readouterr()
    assert code == 2 and captured.out == ""
    assert len(captured.err.strip().splitlines()) == 1 and name in captured.err
    assert not out.exists()


def test_cli_surface_toml_is_accepted_by_contact(tmp_path: Path, capsys) -> None:
    out, plot = tmp_path / "surface.toml", tmp_path / "map.png"
    assert main(["surface", str(AFM / "di-5.di"), "--json", "--out", str(out), "--plot", str(plot)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert plot.read_bytes()[:4] == b"\x89PNG"
    for key in (
        "sq_m",
        "summit_count",
        "summit_density_per_m2",
        "mean_summit_height_m",
        "summit_height_std_m",
        "mean_summit_radius_m",
        "pixel_size_m",
        "scan_size_m",
    ):
        assert key in report
    surface = load_surface(out)
    assert surface.sigma_m == report["sq_m"]
    assert surface.summit_radius_m == report["mean_summit_radius_m"]
    assert main(["contact", "--surface", str(out), "--part", "300x300x50", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["real_area_m2"] > 0
    assert result["separation_m"] > report["mean_summit_height_m"]


def test_cli_two_scans_give_the_equivalent_surface(tmp_path: Path, capsys) -> None:
    first, second = AFM / "di-5.di", AFM / "stp-1.stp"
    assert main(["surface", str(first), str(second), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    a, b = report["scans"]
    assert report["sq_m"] == pytest.approx(np.hypot(a["sq_m"], b["sq_m"]))
    assert 1 / report["mean_summit_radius_m"] == pytest.approx(
        1 / a["mean_summit_radius_m"] + 1 / b["mean_summit_radius_m"]
    )
    assert report["summit_count"] == a["summit_count"] + b["summit_count"]


def test_plain_npy_map_needs_a_pixel_size_and_reads_units(tmp_path: Path, capsys) -> None:
    heights_nm = np.random.default_rng(0).normal(size=(64, 64))
    np.save(tmp_path / "map.npy", heights_nm)
    assert main(["surface", str(tmp_path / "map.npy"), "--json"]) == 2
    assert "--pixel-size" in capsys.readouterr().err
    code = main(
        ["surface", str(tmp_path / "map.npy"), "--pixel-size", "2e-9", "--height-unit", "nm", "--json"]
    )
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    assert report["pixel_size_m"] == [2e-9, 2e-9]
    assert report["scan_size_m"] == pytest.approx([128e-9, 128e-9])
    assert 0.9e-9 < report["sq_m"] < 1.1e-9


@pytest.mark.parametrize("name", READABLE)
def test_shipped_scans_pass_the_plausibility_bounds(name: str) -> None:
    surface = surface_statistics(read_height_map(AFM / name)).surface_parameters(169e9, 0.28)
    assert implausible(surface) is None
    assert implausible(replace(surface, sigma_m=surface.sigma_m * 1e9)) is not None  # nm read as m
