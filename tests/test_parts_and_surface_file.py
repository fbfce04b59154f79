"""Parts, supports and the surface TOML file."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from feeder.errors import InputError
from feeder.parts import GROOVED, Part, Support
from feeder.surface.parameters import DEFAULT_SURFACE, load_surface


def test_part_parse_with_decimals() -> None:
    part = Part.parse("123.5x80x49.9")
    assert (part.length_m, part.width_m, part.thickness_m) == pytest.approx((123.5e-6, 80e-6, 49.9e-6))
    assert part.label == "123.5x80x49.9"
    assert part.weight_n == pytest.approx(2330 * 123.5e-6 * 80e-6 * 49.9e-6 * 9.81)


@pytest.mark.parametrize("text", ["300x300", "-1x2x3", "axbxc", "0x1x1", "1x1x1x1", ""])
def test_part_parse_rejects(text: str) -> None:
    with pytest.raises(InputError) as err:
        Part.parse(text)
    assert err.value.field == "--part"


def test_grooved_fraction_from_period_and_land() -> None:
    assert GROOVED.area_fraction == 0.5
    assert Support("grooved", groove_period_m=40e-6, land_width_m=10e-6).area_fraction == 0.25
    part = Part.parse("300x300x50")
    assert GROOVED.nominal_area_m2(part) == pytest.approx(0.5 * 9e-8)
    with pytest.raises(InputError, match="land_width_m"):
        Support("grooved", groove_period_m=10e-6, land_width_m=20e-6)
    with pytest.raises(InputError, match="--support"):
        Support.parse("sideways")


def test_surface_toml_round_trip(tmp_path: Path) -> None:
    surface = replace(DEFAULT_SURFACE, z_max_m=40e-9)
    path = tmp_path / "surface.toml"
    surface.write_toml(path)
    assert load_surface(path) == surface
    assert DEFAULT_SURFACE.z_max == pytest.approx(32.227e-9 + 10 * 0.482e-9)
    assert DEFAULT_SURFACE.effective_modulus_pa == pytest.approx(91.69e9, rel=1e-4)


def test_surface_file_errors_name_file_and_field(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text(DEFAULT_SURFACE.to_toml().replace("poisson_ratio = 0.28", "poisson_ratio = 0.7"))
    with pytest.raises(InputError) as err:
        load_surface(path)
    assert "s.toml" in str(err.value) and "poisson_ratio" in str(err.value)
    with pytest.raises(InputError, match="no such file"):
        load_surface(tmp_path / "missing.toml")
