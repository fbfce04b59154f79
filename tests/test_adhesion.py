"""Adhesion in the rough contact and τ–w as a pair: w = 0 is the paper's model, every command
pairs τ with its w, the fit of w to the grooved/flat ratio and its sensitivity."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import pytest

from feeder.cli import main
from feeder.contact.adhesion_fit import RATIO_BAND, fit_adhesion_work, grooved_ratio
from feeder.contact.breakaway import contact
from feeder.contact.tau_pair import ADHESION_WORK_REL_BAND, FITTED_ADHESION_WORK_J_M2, fitted_tau, tau_pair
from feeder.errors import InputError
from feeder.paper import GROOVED_FRICTION_RATIO, TAU_MEAN_PA, TAU_SPREAD_PA
from feeder.parts import FLAT, GROOVED, Part
from feeder.planner import plan
from feeder.surface.parameters import DEFAULT_SURFACE

PART = Part.parse("300x300x50")
W = 0.1


def test_zero_work_of_adhesion_is_the_papers_model() -> None:
    plain = contact(PART)
    zero = contact(PART, surface=replace(DEFAULT_SURFACE, adhesion_work_j_m2=0.0))
    assert zero == plain and plain.adhesion_n == 0.0 and plain.summit_tabor is None
    assert (plain.tau_pa, plain.tau_band_pa) == (TAU_MEAN_PA, TAU_SPREAD_PA)


def test_tau_is_fitted_with_w_and_keeps_the_measured_breakaway() -> None:
    surface = replace(DEFAULT_SURFACE, adhesion_work_j_m2=W)
    plain, adhesive = contact(PART), contact(PART, FLAT, surface)
    # τ·A_r on the flat support is the measured force, whatever w: a stays ≈ 105 m/s²
    assert adhesive.breakaway_force_n == pytest.approx(plain.breakaway_force_n, rel=1e-9)
    assert adhesive.breakaway_accel_m_s2 == pytest.approx(105.25, rel=1e-3)
    assert adhesive.tau_pa == pytest.approx(
        TAU_MEAN_PA * plain.real_area_m2 / adhesive.real_area_m2, rel=1e-9
    )
    assert adhesive.tau_pa < 1e7  # the adhesion-free 22 GPa is never paired with w = 0.1
    assert adhesive.tau_adhesion_work_j_m2 == W and "w = 0.1" in adhesive.tau_source
    # a τ that was fitted without adhesion is refused with w > 0; its own w is accepted
    with pytest.raises(InputError, match="--tau"):
        contact(PART, FLAT, surface, tau_pa=TAU_MEAN_PA)
    given = contact(PART, FLAT, surface, tau_pa=3e5, tau_adhesion_work_j_m2=W)
    assert given.tau_pa == 3e5
    assert tau_pair(DEFAULT_SURFACE, 2e10).tau_band_pa == pytest.approx(2e10 * TAU_SPREAD_PA / TAU_MEAN_PA)


def test_planner_receives_only_a_consistent_pair() -> None:
    surface = replace(DEFAULT_SURFACE, adhesion_work_j_m2=W)
    with pytest.raises(InputError, match="fitted with w = 0"):
        plan(PART, FLAT, surface, TAU_MEAN_PA, distance_m=50e-6)
    adhesive = plan(PART, FLAT, surface, distance_m=50e-6)
    plain = plan(PART, FLAT, DEFAULT_SURFACE, distance_m=50e-6)
    assert adhesive.breakaway_accel_m_s2 == pytest.approx(plain.breakaway_accel_m_s2, rel=1e-9)


def test_full_model_fit_of_w_to_the_grooved_ratio() -> None:
    # the constants the defaults rest on are what the model gives
    assert grooved_ratio(DEFAULT_SURFACE, PART, FITTED_ADHESION_WORK_J_M2) == pytest.approx(
        GROOVED_FRICTION_RATIO, abs=2e-4)  # fmt: skip
    lo_w, hi_w = (FITTED_ADHESION_WORK_J_M2 * (1 + s * ADHESION_WORK_REL_BAND) for s in (-1, 1))
    assert grooved_ratio(DEFAULT_SURFACE, PART, lo_w) == pytest.approx(RATIO_BAND[1], abs=0.005)
    assert grooved_ratio(DEFAULT_SURFACE, PART, hi_w) == pytest.approx(RATIO_BAND[0], abs=0.005)
    # with attraction out of contact, w = 0.1 is adhesion-dominated: ratio → nominal-area ratio 0.5
    assert grooved_ratio(DEFAULT_SURFACE, PART, W) == pytest.approx(0.5, abs=1e-3)
    flat = contact(PART, FLAT, replace(DEFAULT_SURFACE, adhesion_work_j_m2=W))
    assert any("adhesion-dominated" in w for w in flat.warnings)


def test_fit_reports_sensitivity_and_unreachable_targets() -> None:
    fit = fit_adhesion_work(DEFAULT_SURFACE, PART, curve_points=4)
    assert fit.adhesion_work_j_m2 == pytest.approx(FITTED_ADHESION_WORK_J_M2, rel=1e-3)
    assert fit.ratio_slope_per_j_m2 is not None and fit.ratio_slope_per_j_m2 < 0
    assert fit.adhesion_work_band_j_m2 is not None
    lo, hi = fit.adhesion_work_band_j_m2
    assert lo < fit.adhesion_work_j_m2 < hi
    assert (hi - lo) / (hi + lo) == pytest.approx(ADHESION_WORK_REL_BAND, rel=0.02)
    none = fit_adhesion_work(DEFAULT_SURFACE, PART, target=0.3, curve_points=3)
    assert none.adhesion_work_j_m2 is None and "no w" in none.explanation


def test_grooved_breakaway_scales_with_the_ratio() -> None:
    surface = replace(DEFAULT_SURFACE, adhesion_work_j_m2=FITTED_ADHESION_WORK_J_M2)
    flat, grooved = contact(PART, FLAT, surface), contact(PART, GROOVED, surface)
    assert grooved.tau_pa == flat.tau_pa == fitted_tau(surface).tau_pa
    assert grooved.breakaway_force_n / flat.breakaway_force_n == pytest.approx(
        GROOVED_FRICTION_RATIO, abs=2e-4
    )


def test_cli_contact_and_tau_pairs(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    replace(DEFAULT_SURFACE, adhesion_work_j_m2=W).write_toml(path)
    assert main(["contact", "--part", "300x300x50", "--surface", str(path), "--json"]) == 0
    from_file = json.loads(capsys.readouterr().out)
    assert main(["contact", "--part", "300x300x50", "--adhesion-work", "0.1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert from_file["real_area_m2"] == pytest.approx(out["real_area_m2"], rel=1e-12)
    assert out["tau_adhesion_work_j_m2"] == 0.1 and out["tau_pa"] < 1e7
    assert out["breakaway_force_N"] == pytest.approx(out["tau_pa"] * out["real_area_m2"], rel=1e-12)
    assert out["breakaway_accel_m_s2"] == pytest.approx(out["breakaway_force_N"] / out["mass_kg"])
    assert out["summit_tabor"] > 0 and out["adhesion_parameter"] > 0 and out["attracted_summits"] > 0
    assert main(["contact", "--table", "--adhesion-work", "0.02", "--placements", "0"]) == 0
    assert capsys.readouterr().out.startswith("Greenwood–Williamson + Maugis–Dugdale")  # was "+ Hertz"
    assert main(["contact", "--part", "300x300x50", "--adhesion-work", "0.1", "--tau", "2e10"]) == 2
    assert "--tau" in capsys.readouterr().err
    with pytest.raises(SystemExit) as usage:  # the range is checked by the option's type
        main(["contact", "--part", "300x300x50", "--adhesion-work", "-1"])
    assert usage.value.code == 2 and "--adhesion-work" in capsys.readouterr().err
    args = ["tau", "--part", "300x300x50", "--force", "0.9759e-6", "--force", "0.9174e-6"]
    assert main([*args, "--adhesion-work", "0.1", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    lo, hi = report["real_area_band_m2"]
    assert report["tau_band_pa"] > 0 and hi - lo > 0.1 * report["real_area_m2"]
    spread = abs(0.9759e-6 - 0.9174e-6) / math.sqrt(2) / ((0.9759e-6 + 0.9174e-6) / 2)
    band = report["inputs"]["area_band"]
    assert report["tau_band_pa"] == pytest.approx(report["tau_pa"] * math.hypot(spread, band), rel=1e-9)


def test_cli_fit_says_plainly_when_no_w_reaches_the_target(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    plot = tmp_path / "fit.png"
    assert main(["adhesion", "fit", "--ratio", "0.3", "--plot", str(plot), "--json"]) == 1  # refused
    captured = capsys.readouterr()
    assert captured.out == "" and "refused: no w" in captured.err and "spans 0.500" in captured.err
    assert not plot.exists()
