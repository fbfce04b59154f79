"""Every example in waveforms/ runs at a small size, saves its figure, and says something true."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from feeder.waveform import load_waveform

WAVEFORMS = Path(__file__).resolve().parents[1] / "waveforms"
PAPER = WAVEFORMS / "paper-100hz-200vpp.toml"
PAPER_STEP_M = 3.298e-6


def example(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"waveforms_{name}", WAVEFORMS / f"{name}.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_example_is_tested():
    tested = {"design_for_part", "flyback_shapes", "step_vs_part_size", "scatter_monte_carlo",
              "design_sweep"}  # fmt: skip
    assert {p.stem for p in WAVEFORMS.glob("*.py")} == tested


def test_design_for_part(tmp_path):
    out = tmp_path / "design.png"
    result = example("design_for_part").run("500x500x50", "paper", "max-step", small=True, out=out)
    assert out.stat().st_size > 1000
    assert result["paper_waveform_step_m"] == pytest.approx(PAPER_STEP_M, rel=2e-3)
    assert result["predicted_step_m"] >= result["paper_waveform_step_m"]
    assert load_waveform(out.with_suffix(".toml")).frequency_hz == result["frequency_hz"]


def test_flyback_shapes(tmp_path):
    out = tmp_path / "shapes.png"
    result = example("flyback_shapes").run("500x500x50", 100.0, 150.0, small=True, out=out)
    assert out.stat().st_size > 1000
    # a half-cosine of the same peak current lasts π/2 longer than a linear flyback
    assert result["half-cosine_fastest_flyback_s"] == pytest.approx(
        np.pi / 2 * result["linear_fastest_flyback_s"]
    )
    # flyback time is what decides (DESIGN §4): the longest commanded flyback steps least
    for shape in ("linear", "half-cosine"):
        steps = result[f"{shape}_steps_m"]
        assert steps[-1] < 0.5 * max(steps)
        assert max(steps) > 0


def test_step_vs_part_size(tmp_path):
    out = tmp_path / "size.png"
    result = example("step_vs_part_size").run(PAPER, 0.1, small=True, out=out)
    assert out.stat().st_size > 1000
    plain = np.array(result["steps_m_w0"])
    np.testing.assert_allclose(plain, plain[0], rtol=2e-3)  # same a_break for every size (DESIGN §2)
    assert plain[0] == pytest.approx(PAPER_STEP_M, rel=2e-3)
    sticky = np.array(result["steps_m_w0.1"])
    np.testing.assert_allclose(sticky, sticky[0], rtol=2e-3)  # adhesion ∝ area, as the weight is
    # τ is refitted with w (the τ–w pair reproduces the paper's forces): the same a_break, the same step
    assert sticky[0] == pytest.approx(plain[0], rel=0.02)


def test_scatter_monte_carlo(tmp_path):
    out = tmp_path / "mc.png"
    result = example("scatter_monte_carlo").run(PAPER, "500x500x50", 0.05, 10, 12, out=out)
    assert out.stat().st_size > 1000
    assert result["net_std_m"] > 0
    assert result["net_mean_m"] == pytest.approx(result["predicted_net_m"], rel=0.1)
    lo, hi = result["predicted_net_band_m"]
    assert lo < result["net_mean_m"] < hi


def test_design_sweep(tmp_path, capsys, monkeypatch):
    out = tmp_path / "sweep.png"
    monkeypatch.setattr(sys, "argv", ["design_sweep.py"])
    assert example("design_sweep").main(["--out", str(out), "--json"]) == 0
    assert out.stat().st_size > 1000
    assert '"paper_waveform_step_m": 3.29' in capsys.readouterr().out
