"""The materials library: the package data, E* of a pair, w of a pair, and --material on the commands."""

from __future__ import annotations

import json
import math

import pytest

from feeder.cli import main
from feeder.materials import adhesion_work, effective_modulus_pa, library, material
from feeder.paper import TAU_MEAN_PA, TAU_SPREAD_PA
from feeder.parts import Part
from feeder.surface.parameters import DEFAULT_SURFACE

FIELDS = ("youngs_modulus_pa", "poisson_ratio", "hardness_pa", "density_kg_m3", "surface_energy_j_m2")


def test_the_library_holds_the_issue_materials_each_field_with_a_source() -> None:
    names = set(library())
    assert names == {"silicon", "silica", "glass", "sapphire", "steel", "gold", "pmma"}
    for m in library().values():
        for key in FIELDS:
            assert key in m.sources, (m.name, key)
            assert getattr(m, key) > 0
        assert 0 < m.poisson_ratio < 0.5
        assert m.hardness_pa < m.youngs_modulus_pa  # H ~ E/10 for brittle solids, far less for metals
    assert material("SiO2") is material("silica") and material("polymer") is material("pmma")
    with pytest.raises(Exception, match="unknown material"):
        material("unobtainium")


def test_silicon_is_the_embedded_surface_and_its_tau_is_the_papers_pair() -> None:
    si = material("si")
    assert effective_modulus_pa(si, si) == pytest.approx(DEFAULT_SURFACE.effective_modulus_pa, rel=1e-14)
    assert si.density_kg_m3 == Part.parse("1x1x1").density_kg_m3
    assert si.hardness_pa == DEFAULT_SURFACE.hardness_pa
    assert si.tau is not None
    assert (si.tau.tau_pa, si.tau.tau_band_pa, si.tau.adhesion_work_j_m2) == (TAU_MEAN_PA, TAU_SPREAD_PA, 0.0)


def test_pair_modulus_and_adhesion_work() -> None:
    si, sapphire = material("silicon"), material("sapphire")
    expected = 1 / ((1 - 0.28**2) / 169e9 + (1 - 0.29**2) / 345e9)  # Johnson eq. 4.22 by hand
    assert effective_modulus_pa(si, sapphire) == pytest.approx(expected, rel=1e-14)
    assert effective_modulus_pa(sapphire, si) == effective_modulus_pa(si, sapphire)
    w, source = adhesion_work(si, si)
    assert w == 0.1 and source.startswith("measured")
    w, source = adhesion_work(si, sapphire)
    assert w == pytest.approx(2 * math.sqrt(0.05 * 0.04)) and "estimate" in source
    assert adhesion_work(sapphire, si) == adhesion_work(si, sapphire)


def _contact(capsys: pytest.CaptureFixture[str], *args: str) -> dict:
    assert main(["contact", "--part", "300x300x50", "--placements", "0", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_material_options_set_density_modulus_and_the_softer_hardness(
    capsys: pytest.CaptureFixture[str],
) -> None:
    base = _contact(capsys)
    assert "part_material" not in base  # no --material: output as before
    same = _contact(capsys, "--material", "silicon")
    assert same["real_area_m2"] == pytest.approx(base["real_area_m2"], rel=1e-12)
    assert same["tau_pa"] == base["tau_pa"] and not any(
        "shear strength is known" in w for w in same["warnings"]
    )
    sapphire = _contact(capsys, "--material", "sapphire")
    assert sapphire["mass_kg"] == pytest.approx(base["mass_kg"] * 3980 / 2330, rel=1e-12)
    assert sapphire["effective_modulus_pa"] == pytest.approx(345e9 / (2 * (1 - 0.29**2)), rel=1e-12)
    mixed = _contact(capsys, "--material", "silicon", "--support-material", "gold")
    assert mixed["hardness_pa"] == 1.5e9  # gold is the softer body
    assert mixed["plasticity_index"] > base["plasticity_index"]
    assert any("no shear strength is known for silicon on gold" in w for w in mixed["warnings"])
    dense = _contact(capsys, "--material", "sapphire", "--density", "1000")
    assert dense["mass_kg"] == pytest.approx(base["mass_kg"] * 1000 / 2330, rel=1e-12)


@pytest.mark.parametrize("command", ["contact", "tau", "plan", "simulate"])
def test_every_part_command_takes_the_material_options(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = capsys.readouterr().out
    assert "--material" in text and "--support-material" in text


def test_unknown_material_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["contact", "--part", "300x300x50", "--support-material", "cheese"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--support-material" in err and "cheese" in err
