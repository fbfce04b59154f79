"""DMT adhesion per summit: against a quad reference, w = 0 is the paper's model, and what
a typical silicon work of adhesion does to the paper's two puzzles (grooved ratio, τ)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq
from test_greenwood_williamson import Reference, random_surface

from feeder.cli import main
from feeder.contact.breakaway import IDEAL_SHEAR_STRENGTH_PA, contact, tabor_parameter
from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.paper import GROOVED_FRICTION_RATIO, RAW_FORCES_300_FLAT_N
from feeder.parts import FLAT, GROOVED, Part
from feeder.surface.parameters import DEFAULT_SURFACE

SILICON_IN_AIR_J_M2 = 0.1


class DmtReference(Reference):
    """Net load N∫(4/3 E* R^½ δ^{3/2} − 2πwR) φ dz over contacting summits, with quad."""

    def load(self, d: float) -> float:
        pull = 2 * math.pi * self.s.adhesion_work_j_m2 * self.s.summit_radius_m
        return super().load(d) - pull * self.contacts(d)

    def separation(self, load: float) -> float:
        lo = self.s.mean_summit_height_m - 6 * self.s.sigma_m
        hi = brentq(lambda d: super(DmtReference, self).load(d) - load, lo, self.s.z_max, rtol=1e-14)
        return brentq(lambda d: self.load(d) - load, lo, hi, xtol=1e-24, rtol=1e-14)


@pytest.mark.parametrize("seed", range(4))
def test_net_load_and_separation_match_quad_reference(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    surface = replace(random_surface(rng), adhesion_work_j_m2=rng.uniform(0.001, 0.05))
    area = rng.uniform(1e-9, 1e-6)
    gw, ref = GreenwoodWilliamson(surface, area), DmtReference(surface, area)
    d0 = surface.mean_summit_height_m + surface.sigma_m * rng.uniform(-1.0, 2.0)
    assert float(gw.load_n(d0)) == pytest.approx(ref.load(d0), rel=1e-8)
    load = ref.load(d0)
    assert load > 0  # these surfaces are compressed at d0, adhesion or not
    assert float(gw.separation_m(load)) == pytest.approx(ref.separation(load), rel=1e-10)


def test_zero_work_of_adhesion_is_the_papers_model() -> None:
    part = Part.parse("300x300x50")
    plain = contact(part)
    zero = contact(part, surface=replace(DEFAULT_SURFACE, adhesion_work_j_m2=0.0))
    assert zero == plain and plain.adhesion_n == 0.0


def test_separation_unique_and_round_trips_with_adhesion() -> None:
    gw = GreenwoodWilliamson(replace(DEFAULT_SURFACE, adhesion_work_j_m2=SILICON_IN_AIR_J_M2), 9e-8)
    loads = np.geomspace(1e-9, 0.5 * gw.max_load_n, 5000)
    d = gw.separation_m(loads)
    assert np.all(np.diff(d) < 0)
    np.testing.assert_allclose(gw.load_n(d), loads, rtol=1e-9)
    # more adhesion → more compression at the same weight
    plain = GreenwoodWilliamson(DEFAULT_SURFACE, 9e-8)
    assert np.all(d < plain.separation_m(loads))


def test_silicon_adhesion_explains_the_grooved_ratio_and_a_sub_ideal_tau() -> None:
    surface = replace(DEFAULT_SURFACE, adhesion_work_j_m2=SILICON_IN_AIR_J_M2)
    part = Part.parse("300x300x50")
    flat, grooved = contact(part, FLAT, surface), contact(part, GROOVED, surface)
    assert grooved.real_area_m2 / flat.real_area_m2 == pytest.approx(GROOVED_FRICTION_RATIO, abs=0.02)
    assert flat.contacts > 10  # and GW's statistics hold again
    tau = float(np.mean(RAW_FORCES_300_FLAT_N)) / flat.real_area_m2
    assert tau < IDEAL_SHEAR_STRENGTH_PA
    assert flat.adhesion_n > part.weight_n
    assert any("adhesion-dominated" in w for w in flat.warnings)
    assert 0.05 < tabor_parameter(surface) < 0.5  # DMT regime, borderline


def test_cli_option_and_surface_file(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    replace(DEFAULT_SURFACE, adhesion_work_j_m2=0.05).write_toml(path)
    assert main(["contact", "--part", "300x300x50", "--surface", str(path), "--json"]) == 0
    from_file = json.loads(capsys.readouterr().out)
    assert main(["contact", "--part", "300x300x50", "--adhesion-work", "0.05", "--json"]) == 0
    from_option = json.loads(capsys.readouterr().out)
    assert from_file["adhesion_work_j_m2"] == from_option["adhesion_work_j_m2"] == 0.05
    assert from_file["real_area_m2"] == pytest.approx(from_option["real_area_m2"], rel=1e-12)
    assert main(["contact", "--part", "300x300x50", "--adhesion-work", "-1"]) == 2
    assert "--adhesion-work" in capsys.readouterr().err
