"""`feeder figures`: Fig. 9 and the τ tables recomputed from the paper's printed F and A_r."""

from __future__ import annotations

import json
import statistics
from pathlib import Path

import pytest

from feeder.cli import main
from feeder.paper import PAPER_ROWS, SEPARATION_FLAT_M, TAU_MEAN_PA, TAU_SPREAD_PA

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_figures_json(tmp_path: Path, capsys) -> None:
    out = tmp_path / "figs"
    assert main(["figures", "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert sorted(Path(f).name for f in report["files"]) == ["fig9_load_vs_separation.png", "tau_tables.png"]
    for name in report["files"]:
        assert Path(name).read_bytes()[:8] == PNG_MAGIC
    assert report["fig9"]["separation_flat_m"] == pytest.approx(SEPARATION_FLAT_M, abs=0.01e-9)
    assert report["fig9"]["separation_grooved_m"] < report["fig9"]["separation_flat_m"]
    rows = {(r["part"], r["support"]): r for r in report["tau_table"]}
    hundred = rows[("100x100x50", "flat")]
    assert hundred["tau_recomputed_pa"] == pytest.approx(0.17e-6 / 0.55259e-17)
    assert hundred["tau_recomputed_pa"] == pytest.approx(30.8e9, rel=2e-3)
    assert hundred["tau_printed_pa"] == 25.33e9
    for label, paper in PAPER_ROWS.items():
        row = rows[(label, "flat")]
        assert row["tau_recomputed_pa"] == pytest.approx(paper.friction_flat_n / paper.real_area_flat_m2)
    raw = rows[("300x300x50", "flat, raw F (Table IV)")]
    assert raw["tau_recomputed_pa"] == pytest.approx(19.03e9, rel=1e-3)
    summary = report["tau_summary"]
    printed = [p.tau_pa for p in PAPER_ROWS.values()]
    assert summary["midpoint_half_range_of_19_03_and_25_33_pa"] == pytest.approx([TAU_MEAN_PA, TAU_SPREAD_PA])
    mean_std = [statistics.mean(printed), statistics.stdev(printed)]
    assert summary["printed_tau_mean_std_pa"] == pytest.approx(mean_std)
    assert summary["printed_tau_mean_std_pa"][0] != pytest.approx(TAU_MEAN_PA, rel=0.02)
    notes = " ".join(report["notes"])
    for phrase in ("30.8 GPa", "25.33", "22.18 +/- 3.15", "does not follow"):
        assert phrase in notes


def test_figures_text_output_says_what_does_not_follow(tmp_path: Path, capsys) -> None:
    assert main(["figures", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "30.8 GPa" in text and "does not follow" in text


def test_figures_out_must_be_a_directory(tmp_path: Path, capsys) -> None:
    target = tmp_path / "file.txt"
    target.write_text("x")
    assert main(["figures", "--out", str(target), "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.strip().splitlines()) == 1
