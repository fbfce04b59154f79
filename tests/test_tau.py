"""τ = F/A_r: closed-form propagation, the paper's 300×300 numbers, force-curve inputs, bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from feeder.cli import main
from feeder.errors import InputError
from feeder.friction.shear_strength import shear_strength
from feeder.paper import PAPER_ROWS, RAW_FORCES_300_FLAT_N, RAW_FORCES_300_GROOVED_N

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "force_curves"


def test_tau_and_band_closed_form() -> None:
    result = shear_strength([1.0e-6, 1.2e-6, 0.8e-6], 5e-17, real_area_rel_band=0.1)
    assert result.tau_pa == pytest.approx(1.0e-6 / 5e-17)
    assert result.force_spread_n == pytest.approx(0.2e-6)  # sample std, ddof = 1
    assert result.tau_band_pa == pytest.approx(result.tau_pa * math.hypot(0.2, 0.1))
    assert result.real_area_band_m2 == pytest.approx((4.5e-17, 5.5e-17))
    single = shear_strength([1.0e-6], 5e-17)
    assert (single.force_spread_n, single.tau_band_pa) == (0.0, 0.0)
    with pytest.raises(InputError, match="--force"):
        shear_strength([1e-6, -1e-6], 5e-17)
    with pytest.raises(InputError, match="--area-band"):
        shear_strength([1e-6], 5e-17, 1.5)


def test_cli_reproduces_the_paper_300x300_flat(capsys) -> None:
    args = ["tau", "--part", "300x300x50", "--support", "flat", "--json"]
    for force in RAW_FORCES_300_FLAT_N:
        args += ["--force", repr(force)]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    mean = sum(RAW_FORCES_300_FLAT_N) / 2
    assert report["real_area_m2"] == pytest.approx(PAPER_ROWS["300x300x50"].real_area_flat_m2, rel=1e-3)
    assert report["tau_pa"] == pytest.approx(PAPER_ROWS["300x300x50"].tau_pa, rel=1e-3)  # 19.03 GPa
    spread = abs(RAW_FORCES_300_FLAT_N[0] - RAW_FORCES_300_FLAT_N[1]) / math.sqrt(2)
    # two forces: their spread holds the placement scatter, which is not added again; w = 0: no w band
    assert report["inputs"]["area_band"] == 0.0
    assert report["tau_band_pa"] == pytest.approx(report["tau_pa"] * spread / mean)
    assert main(["tau", "--part", "300x300x50", "--force", repr(mean), "--json"]) == 0
    single = json.loads(capsys.readouterr().out)  # one force: the predicted placement scatter stands in
    assert single["inputs"]["scatter_source"] == "placement sampling"
    assert 0.05 < single["tau_band_pa"] / single["tau_pa"] < 0.3
    assert report["inputs"]["forces_N"] == list(RAW_FORCES_300_FLAT_N)
    assert any("ideal shear strength" in w for w in report["warnings"])


def test_cli_given_real_area_and_area_band(capsys) -> None:
    area = PAPER_ROWS["300x300x50"].real_area_grooved_m2
    args = [
        "tau",
        "--part",
        "300x300x50",
        "--support",
        "grooved",
        "--real-area",
        repr(area),
        "--area-band",
        "0.05",
        "--json",
    ]
    for force in RAW_FORCES_300_GROOVED_N:
        args += ["--force", repr(force)]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    mean = sum(RAW_FORCES_300_GROOVED_N) / 2
    spread = abs(RAW_FORCES_300_GROOVED_N[0] - RAW_FORCES_300_GROOVED_N[1]) / math.sqrt(2)
    assert report["tau_pa"] == pytest.approx(mean / area)
    assert report["tau_band_pa"] == pytest.approx(mean / area * math.hypot(spread / mean, 0.05))
    assert report["inputs"]["real_area_source"] == "--real-area"


def test_cli_accepts_force_curve_files(capsys) -> None:
    files = sorted(EXAMPLES.glob("flat_300x300_*.csv"))
    args = ["tau", "--part", "300x300x50", "--json"]
    for path in files:
        args += ["--force", str(path)]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["inputs"]["force_sources"] == [str(p) for p in files]
    assert report["tau_pa"] == pytest.approx(PAPER_ROWS["300x300x50"].tau_pa, rel=0.02)


@pytest.mark.parametrize("force", ["nope.csv", "-1e-6", "nan"])
def test_cli_bad_force_exits_2_with_one_line(force: str, capsys) -> None:
    assert main(["tau", "--part", "300x300x50", f"--force={force}", "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.strip().splitlines()) == 1
    assert "--force" in captured.err


def test_cli_negative_force_in_scientific_notation_reaches_the_force_check(capsys) -> None:
    # without '=': argparse used to take -1e-6 for an option ("expected one argument")
    assert main(["tau", "--part", "300x300x50", "--force", "-1e-6", "--json"]) == 2
    err = capsys.readouterr().err
    assert "--force: must be a positive force in newtons" in err and err.count("\n") == 1


def test_cli_warns_of_a_force_far_above_the_weight(capsys) -> None:
    assert main(["tau", "--part", "300x300x50", "--force", "1", "--json"]) == 0  # 1 N, meant 1 µN
    report = json.loads(capsys.readouterr().out)
    (warning,) = [w for w in report["warnings"] if "wrong unit" in w]
    assert warning.startswith("--force 1 N is 9.72e+06× the part's weight (1.03e-07 N)")
    assert main(["tau", "--part", "300x300x50", "--force", "1"]) == 0
    assert "warning: --force 1 N is 9.72e+06×" in capsys.readouterr().out
    for force in RAW_FORCES_300_FLAT_N:  # the paper's: ~9× the weight, no such warning
        assert main(["tau", "--part", "300x300x50", "--force", repr(force), "--json"]) == 0
        assert not any("wrong unit" in w for w in json.loads(capsys.readouterr().out)["warnings"])
