"""One sphere on a flat: Hertz, DMT, JKR and Maugis–Dugdale against closed forms, limits,
a published value and (when installed) the ``adhesion`` package's independent MD code."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from feeder.cli import main
from feeder.contact.adhesion_sphere import (
    SphereContact,
    _md_residual,
    _md_t,
    maugis_dugdale,
    md_edge_of_contact,
    md_pull_off,
)

R, E_STAR, W = 55e-9, 91.69e9, 0.1


def test_dmt_and_jkr_pull_off_closed_forms() -> None:
    sphere = SphereContact(R, E_STAR, W, 0.2)
    assert sphere.pull_off_n("dmt") == pytest.approx(2 * math.pi * W * R, rel=1e-9)
    assert sphere.pull_off_n("jkr") == pytest.approx(1.5 * math.pi * W * R, rel=1e-9)
    assert sphere.pull_off_n("hertz") == 0.0
    # the JKR curve itself has its load minimum at −1.5 πwR (and the DMT one at −2 πwR)
    best = minimize_scalar(
        lambda a: float(sphere._normalised("jkr", np.array([a]))[0][0]),
        bounds=(0.1, 3.0),
        method="bounded",
        options={"xatol": 1e-10},
    )
    assert -best.fun == pytest.approx(1.5, rel=1e-9)
    assert best.x == pytest.approx((6 / 4) ** (1 / 3), rel=1e-6)  # ā_c^{3/2} = √6/2


def test_hertz_and_closed_form_states() -> None:
    sphere = SphereContact(R, E_STAR, W, 0.2)
    k, load = 4 * E_STAR / 3, 5e-9
    a, delta = sphere.state_at_load("hertz", load)
    assert a == pytest.approx((load * R / k) ** (1 / 3), rel=1e-12)
    assert delta == pytest.approx(a * a / R, rel=1e-12)
    a_dmt, _ = sphere.state_at_load("dmt", load)
    assert a_dmt == pytest.approx(((load + 2 * math.pi * W * R) * R / k) ** (1 / 3), rel=1e-12)
    a_jkr, d_jkr = sphere.state_at_load("jkr", load)
    p_back = k * a_jkr**3 / R - math.sqrt(6 * math.pi * W * k * a_jkr**3)
    assert p_back == pytest.approx(load, rel=1e-10)
    assert d_jkr == pytest.approx(a_jkr**2 / R - 2 / 3 * math.sqrt(6 * math.pi * W * a_jkr / k), rel=1e-10)


@pytest.mark.parametrize("lam", [0.01, 0.3, 1.0, 10.0])
def test_md_equation_solved_to_machine_precision(lam: float) -> None:
    abar = np.geomspace(1e-5, 50.0, 300)
    t = _md_t(abar, lam)
    scale = 0.5 * lam * abar**2 * (t + (t * t + 1) * np.arctan(t)) + 1.0  # size of the terms
    assert np.max(np.abs(_md_residual(t, abar, lam)) / scale) < 1e-14


def test_md_tends_to_dmt_and_jkr() -> None:
    dmt, jkr = md_pull_off(0.01)[0], md_pull_off(10.0)[0]
    assert dmt == pytest.approx(2.0, rel=0.01)
    assert jkr == pytest.approx(1.5, rel=0.01)
    assert dmt != pytest.approx(2.0, rel=1e-4)  # a real MD value, not the limit copied
    # states at a load follow too (contact radius within 1 %)
    load = 3e-9
    small, large = SphereContact(R, E_STAR, W, 0.01), SphereContact(R, E_STAR, W, 10.0)
    assert small.state_at_load("maugis-dugdale", load)[0] == pytest.approx(
        small.state_at_load("dmt", load)[0], rel=0.01
    )
    assert large.state_at_load("maugis-dugdale", load)[0] == pytest.approx(
        large.state_at_load("jkr", load)[0], rel=0.01
    )
    lams = [0.01, 0.1, 0.3, 1.0, 3.0, 10.0]
    assert np.all(np.diff([md_pull_off(x)[0] for x in lams]) < 0)  # monotone DMT → JKR


def test_md_intermediate_published_value() -> None:
    # λ = 1: −P̄_c = 1.60 (Johnson & Greenwood 1997's fit 7/4 − ¼(4.04λ^¼ − 1)/(4.04λ^¼ + 1) = 1.599;
    # Maugis 1992, fig. 5)
    assert md_pull_off(1.0)[0] == pytest.approx(1.599, abs=0.005)


def test_md_non_contact_branch_joins_the_contact_branch() -> None:
    lam = 0.5
    edge = md_edge_of_contact(lam)
    load, approach, m = maugis_dugdale(np.array([1e-7]), lam)
    assert load[0] == pytest.approx(-math.pi * lam / 2 * edge**2, rel=1e-5)
    assert approach[0] == pytest.approx(-4 / 3 * lam * edge, rel=1e-5)
    assert m[0] * 1e-7 == pytest.approx(edge, rel=1e-5)


def test_md_state_round_trips_on_the_stable_branch() -> None:
    sphere = SphereContact(R, E_STAR, W, 0.7)
    for load in (-0.9 * sphere.pull_off_n("maugis-dugdale"), 0.0, 1e-9, 1e-7):
        a, delta = sphere.state_at_load("maugis-dugdale", load)
        p_bar, d_bar, _ = maugis_dugdale(np.array([a / sphere.radius_unit_m]), sphere.tabor)
        assert p_bar[0] * sphere.load_unit_n == pytest.approx(load, abs=1e-12 * sphere.load_unit_n)
        assert d_bar[0] * sphere.approach_unit_m == pytest.approx(delta, rel=1e-12)


def test_range_and_tabor_are_one_parameter() -> None:
    sphere = SphereContact.from_range(R, E_STAR, W, 0.3e-9)
    assert sphere.dugdale_range_m == pytest.approx(0.3e-9, rel=1e-12)
    assert sphere.dugdale_stress_pa * sphere.dugdale_range_m == pytest.approx(W, rel=1e-12)


@pytest.mark.parametrize("lam", [0.1, 0.5, 1.0, 3.0])
def test_md_against_the_adhesion_package(lam: float) -> None:
    reference = pytest.importorskip("Adhesion.ReferenceSolutions.MaugisDugdale")
    abar = np.array([0.05, 0.3, 1.0, 2.5])
    load, approach, _ = maugis_dugdale(abar, lam)
    ref_load, ref_approach = reference._load_and_displacement(abar, lam)
    np.testing.assert_allclose(load, ref_load, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(approach, ref_approach, rtol=1e-9, atol=1e-12)
    grid = np.geomspace(1e-3, 4.0, 4000)
    assert md_pull_off(lam)[0] == pytest.approx(-np.min(reference._load(grid, lam)), rel=1e-5)


def test_cli_sphere(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    base = ["adhesion", "sphere", "--radius", "55e-9", "--modulus", "91.69e9", "--adhesion-work", "0.1"]
    assert main([*base, "--model", "dmt", "--load", "1e-9", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["pull_off_n"] == pytest.approx(2 * math.pi * W * R, rel=1e-12)
    assert out["contact_radius_m"] > 0 and out["approach_m"] > 0 and out["tabor"] > 0
    assert main([*base, "--tabor", "1", "--curve", "--plot", str(tmp_path / "c.png"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["tabor"] == 1.0 and out["pull_off_n"] == pytest.approx(1.6007 * math.pi * W * R, rel=1e-3)
    assert min(out["curve"]["load_n"]) >= -out["pull_off_n"] * (1 + 1e-9)
    assert (tmp_path / "c.png").stat().st_size > 1000
    assert main([*base, "--load", "-1"]) == 2
    assert "--load" in capsys.readouterr().err
    # a tensile load in exponent notation is a value (argparse took "-1e-10" for an option)
    assert main([*base, "--model", "dmt", "--load", "-1e-10", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["contact_radius_m"] > 0
    with pytest.raises(SystemExit) as usage:  # the range is checked by the option's type
        main([*base, "--tabor", "-2"])
    assert usage.value.code == 2 and "--tabor" in capsys.readouterr().err
