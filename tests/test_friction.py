"""Force-curve analysis: generated curves with known peaks, the shipped examples, presets,
bad CSV files (one-line errors, exit 2) and `feeder friction`."""

from __future__ import annotations

import importlib.util
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from feeder.cli import main
from feeder.errors import InputError
from feeder.friction.cantilevers import CANTILEVERS, cantilever_stiffness
from feeder.friction.force_curves import (
    ForceCurve,
    analyse_force_curve,
    read_force_curve,
    summarize,
    write_force_curve,
)
from feeder.friction.synthetic_curves import CurveShape, synthetic_force_curve

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "force_curves"

# the paper's mean forces per part size, with the cantilever suited to each (Tables II, V)
PAPER_CURVES = [(0.94e-6, "TL-FM"), (0.37e-6, "TL-FM"), (0.17e-6, "NSC35"), (0.08e-6, "NSC35")]


def test_cantilever_presets_are_table_ii() -> None:
    assert CANTILEVERS["TL-FM"].stiffness_n_per_m == 2.08
    assert CANTILEVERS["NSC35"].stiffness_n_per_m == 1.25
    assert CANTILEVERS["TL-FM"].resonance_hz == 70.42e3
    assert cantilever_stiffness("nsc35") == 1.25
    assert cantilever_stiffness("TL-FM", 3.0) == 3.0
    assert cantilever_stiffness(None) is None
    with pytest.raises(InputError, match="--cantilever"):
        cantilever_stiffness("XYZ")


@pytest.mark.parametrize(("peak", "lever"), PAPER_CURVES)
def test_peak_recovered_within_2_percent_at_realistic_noise(peak: float, lever: str) -> None:
    stiffness = CANTILEVERS[lever].stiffness_n_per_m
    shape = CurveShape()  # 1 nm rms deflection noise, 20 nm drift, 150 nm offset
    for seed in range(8):
        x, deflection = synthetic_force_curve(peak, stiffness, shape, seed)
        result = analyse_force_curve(ForceCurve(x, stiffness * deflection, "generated", stiffness))
        assert result.static_friction_n == pytest.approx(peak, rel=0.02)
        assert result.sliding_force_n == pytest.approx(shape.kinetic_ratio * peak, rel=0.03)
        u_peak = peak / (stiffness * shape.contact_stiffness_ratio)
        contact = shape.free_fraction * shape.samples * u_peak / (shape.loading_fraction * shape.samples)
        assert abs(result.contact_onset_m - contact) < 0.03 * u_peak
        assert result.noise_n == pytest.approx(shape.noise_deflection_m * stiffness, rel=0.2)


def test_offset_and_drift_do_not_move_the_peak() -> None:
    quiet = CurveShape(noise_deflection_m=1e-12, drift_m=0.0, offset_m=0.0)
    messy = replace(quiet, drift_m=300e-9, offset_m=-4e-6)
    peaks = []
    for shape in (quiet, messy):
        x, deflection = synthetic_force_curve(0.5e-6, 2.08, shape, seed=0)
        peaks.append(analyse_force_curve(ForceCurve(x, 2.08 * deflection, "g", 2.08)).static_friction_n)
    assert peaks[0] == pytest.approx(0.5e-6, rel=2e-3)
    assert peaks[1] == pytest.approx(peaks[0], rel=1e-4)


def test_summary_mean_and_sample_std() -> None:
    results = []
    for seed, peak in enumerate((0.9759e-6, 0.9174e-6)):
        x, deflection = synthetic_force_curve(peak, 2.08, CurveShape(noise_deflection_m=1e-12), seed)
        results.append(analyse_force_curve(ForceCurve(x, 2.08 * deflection, "g", 2.08)))
    summary = summarize(results)
    forces = [r.static_friction_n for r in results]
    assert summary.mean_static_friction_n == pytest.approx(sum(forces) / 2)
    assert summary.static_friction_std_n == pytest.approx(abs(forces[0] - forces[1]) / math.sqrt(2))
    assert summary.static_friction_sem_n == pytest.approx(summary.static_friction_std_n / math.sqrt(2))
    assert summary.mean_static_friction_n == pytest.approx(0.94665e-6, rel=2e-3)


def _true_peak(path: Path) -> float:
    for line in path.read_text().splitlines():
        if line.startswith("# true_static_friction_n"):
            return float(line.split("=")[1])
    raise AssertionError(f"{path} has no true peak")


def test_shipped_examples_are_what_the_generator_makes(tmp_path: Path) -> None:
    spec = importlib.util.spec_from_file_location("generate", EXAMPLES / "generate.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main(tmp_path)
    shipped = sorted(p.name for p in EXAMPLES.glob("*.csv"))
    assert shipped == sorted(p.name for p in tmp_path.glob("*.csv")) and len(shipped) >= 4
    for name in shipped:
        made, kept = (tmp_path / name).read_text(), (EXAMPLES / name).read_text()
        assert _header(made) == _header(kept)
        np.testing.assert_allclose(_numbers(made), _numbers(kept), rtol=1e-6, atol=1e-15)


def _header(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("#") or "_m" in line]


def _numbers(text: str) -> np.ndarray:
    rows = [line for line in text.splitlines() if not line.startswith("#") and "_m" not in line]
    return np.loadtxt(rows, delimiter=",")


@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.csv")), ids=lambda p: p.name)
def test_shipped_example_peaks(path: Path) -> None:
    result = analyse_force_curve(read_force_curve(path))
    assert result.static_friction_n == pytest.approx(_true_peak(path), rel=0.02)


def test_force_column_and_stiffness_override(tmp_path: Path) -> None:
    x, deflection = synthetic_force_curve(0.3e-6, 1.25, CurveShape(), seed=9)
    path = tmp_path / "force.csv"
    pairs = enumerate(zip(x.tolist(), deflection.tolist(), strict=True))
    lines = ["time_s,displacement_m,force_n"] + [f"{i * 1e-3},{a!r},{1.25 * b!r}" for i, (a, b) in pairs]
    path.write_text("\n".join(lines) + "\n")
    curve = read_force_curve(path)
    assert curve.stiffness_n_per_m is None
    assert analyse_force_curve(curve).static_friction_n == pytest.approx(0.3e-6, rel=0.02)
    deflection_file = tmp_path / "deflection.csv"
    write_force_curve(deflection_file, x, deflection, {"cantilever": "NSC35"})
    assert read_force_curve(deflection_file).stiffness_n_per_m == 1.25
    assert read_force_curve(deflection_file, 2.5).force_n[0] == pytest.approx(2.5 * deflection[0], rel=1e-6)
    # a stiffness other than the header's cantilever is used, and said (it was silent: 66 % off)
    assert read_force_curve(deflection_file).warnings == ()
    (warning,) = read_force_curve(deflection_file, 2.5).warnings
    assert "2.5 N/m" in warning and "1.25 N/m (NSC35)" in warning
    assert read_force_curve(deflection_file, 1.251).warnings == ()


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _rows(n: int = 100) -> str:
    return "\n".join(f"{i * 1e-9},{i * 1e-10}" for i in range(n))


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("missing.csv", "displacement_m,height_m\n" + _rows(), "missing column"),
        (
            "nan.csv",
            "# stiffness_n_per_m = 2\ndisplacement_m,deflection_m\n" + _rows(60) + "\n1e-6,nan\n",
            "line 63: deflection_m is 'nan'",
        ),
        ("text.csv", "# cantilever = TL-FM\ndisplacement_m,deflection_m\n0.1,abc\n", "line 3"),
        ("short.csv", "# cantilever = TL-FM\ndisplacement_m,deflection_m\n" + _rows(10), "at least 50"),
        ("empty.csv", "# nothing\n", "no header"),
    ],
)
def test_bad_csv_is_one_line_input_error(tmp_path: Path, name: str, text: str, message: str, capsys) -> None:
    path = _write(tmp_path, name, text)
    with pytest.raises(InputError, match=message) as caught:
        read_force_curve(path)
    assert name in str(caught.value)
    assert main(["friction", str(path), "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.strip().splitlines()) == 1 and name in captured.err


def test_deflection_without_stiffness_is_an_error(tmp_path: Path) -> None:
    path = _write(tmp_path, "plain.csv", "displacement_m,deflection_m\n" + _rows())
    with pytest.raises(InputError, match="--stiffness"):
        read_force_curve(path)


def test_curves_without_contact_or_slip_are_errors() -> None:
    x = np.linspace(0, 1e-6, 1000)
    noise = np.random.default_rng(0).normal(0, 1e-9, x.size)
    with pytest.raises(InputError, match="no contact"):
        analyse_force_curve(ForceCurve(x, noise, "flat.csv"))
    ramp = np.clip(x - 0.5e-6, 0, None) * 2.0 + noise
    with pytest.raises(InputError, match="no slip"):
        analyse_force_curve(ForceCurve(x, ramp, "ramp.csv"))


def test_cli_friction_json_and_plot(tmp_path: Path, capsys) -> None:
    files = sorted(EXAMPLES.glob("flat_300x300_*.csv"))
    plot = tmp_path / "curves.png"
    assert main(["friction", *map(str, files), "--json", "--plot", str(plot)]) == 0
    report = json.loads(capsys.readouterr().out)
    truth = [_true_peak(p) for p in files]
    assert report["count"] == 2
    assert report["mean_static_friction_N"] == pytest.approx(np.mean(truth), rel=0.02)
    assert report["static_friction_std_N"] == pytest.approx(np.std(truth, ddof=1), rel=0.1)
    assert [c["stiffness_N_per_m"] for c in report["curves"]] == [2.08, 2.08]
    assert plot.stat().st_size > 10_000
