"""Waveforms: shapes, DAC and ANC300 tables, TOML files and their validation, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from feeder.cli import main
from feeder.errors import InputError
from feeder.plant.amplifier import AmplifierLimits
from feeder.waveform import Waveform, load_waveform

REPO = Path(__file__).resolve().parents[1]
PAPER = REPO / "waveforms" / "paper-100hz-200vpp.toml"


def test_linear_sawtooth_shape() -> None:
    w = Waveform(frequency_hz=100, amplitude_vpp=200, flyback_shape="linear", flyback_s=1e-3)
    phase = np.array([0.0, 0.45, 0.9, 0.95, 0.999999])
    np.testing.assert_allclose(w.shape_at(phase), [0.0, 0.5, 1.0, 0.5, 1e-5], atol=1e-9)
    np.testing.assert_allclose(w.voltage_at(np.array([0.0045, 0.0095])), [100.0, 100.0], atol=1e-9)
    back = Waveform(
        frequency_hz=100, amplitude_vpp=200, flyback_shape="linear", flyback_s=1e-3, direction="backward"
    )
    np.testing.assert_allclose(back.shape_at(phase), 1 - w.shape_at(phase))


def test_half_cosine_and_current_limited_shapes() -> None:
    hc = Waveform(frequency_hz=100, amplitude_vpp=1, flyback_shape="half-cosine", flyback_s=2e-3)
    phase = np.array([0.8, 0.85, 0.9])  # flyback = last 20 % of the period
    np.testing.assert_allclose(hc.shape_at(phase), [1.0, 0.5 * (1 + np.cos(np.pi / 4)), 0.5])
    cl = Waveform(frequency_hz=100, amplitude_vpp=1)
    assert cl.command_flyback_s == 0.0
    assert cl.shape_at(0.999) == pytest.approx(0.999)
    assert cl.shape_at(1.0) == 0.0


def test_dac_and_anc300_tables() -> None:
    w = Waveform(frequency_hz=100, amplitude_vpp=200, flyback_shape="linear", flyback_s=1e-3)
    codes = w.dac_table(1000)
    assert codes.dtype == np.uint16 and codes.size == 1000
    assert codes.min() == 0 and codes.max() == 65535
    assert codes[450] == round(0.5 * 65535)
    up, down = w.anc300_tables()
    assert len(up) == len(down) == 256
    assert min(up) == 0 and max(up) == 255 and all(0 <= v <= 255 for v in up + down)
    assert [255 - v for v in up] == down
    rising = np.diff(up[: int(0.9 * 256)])
    assert np.all(rising >= 0)  # slow rise first, then the fast fall
    with pytest.raises(InputError, match="bits"):
        w.dac_table(100, bits=17)


def test_paper_file_loads_and_round_trips(tmp_path: Path) -> None:
    w = load_waveform(PAPER)
    assert (w.frequency_hz, w.amplitude_vpp, w.flyback_shape) == (100.0, 200.0, "current-limited")
    AmplifierLimits().check(w)
    w2 = Waveform(
        frequency_hz=250,
        amplitude_vpp=120,
        offset_v=10,
        flyback_shape="half-cosine",
        flyback_s=2e-4,
        direction="backward",
    )
    path = tmp_path / "w.toml"
    w2.write_toml(path)
    assert load_waveform(path) == w2


BAD = {
    "flyback longer than the period": (
        'frequency_hz = 100.0\namplitude_vpp = 100.0\nflyback_shape = "linear"\nflyback_s = 0.02',
        "flyback_s",
    ),
    "unknown shape": ('shape = "square"\nfrequency_hz = 100.0\namplitude_vpp = 100.0', "shape"),
    "unknown flyback shape": (
        'frequency_hz = 100.0\namplitude_vpp = 100.0\nflyback_shape = "cubic"',
        "flyback_shape",
    ),
    "negative frequency": ("frequency_hz = -100.0\namplitude_vpp = 100.0", "frequency_hz"),
    "text for a number": ('frequency_hz = "fast"\namplitude_vpp = 100.0', "frequency_hz"),
    "unknown field": ("frequency_hz = 100.0\namplitude_vpp = 100.0\ncolour = 3", "colour"),
    "missing amplitude": ("frequency_hz = 100.0", "amplitude_vpp"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_invalid_files_name_the_field(tmp_path: Path, case: str) -> None:
    body, field = BAD[case]
    path = tmp_path / "bad.toml"
    path.write_text("[waveform]\n" + body + "\n")
    with pytest.raises(InputError) as err:
        load_waveform(path)
    assert field in str(err.value) and str(path) in str(err.value)


def test_amplitude_above_the_rail_is_refused() -> None:
    with pytest.raises(InputError, match=r"amplitude_vpp.*rails"):
        AmplifierLimits().check(Waveform(frequency_hz=100, amplitude_vpp=250))
    with pytest.raises(InputError, match="amplitude_vpp"):
        AmplifierLimits().check(Waveform(frequency_hz=100, amplitude_vpp=150, offset_v=60))


def write(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "w.toml"
    path.write_text("[waveform]\n" + body + "\n")
    return path


@pytest.mark.parametrize(
    "body",
    [
        "frequency_hz = 100.0\namplitude_vpp = 250.0",
        'frequency_hz = 100.0\namplitude_vpp = 100.0\nflyback_shape = "linear"\nflyback_s = 0.5',
        'shape = "triangle"\nfrequency_hz = 100.0\namplitude_vpp = 100.0',
        "frequency_hz = -5.0\namplitude_vpp = 100.0",
        "not toml at all [",
    ],
)
def test_cli_one_line_error_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], body: str) -> None:
    path = write(tmp_path, body)
    for argv in (
        ["waveform", "show", str(path), "--json"],
        ["simulate", "--part", "500x500x50", "--waveform", str(path), "--json"],
    ):
        assert main(argv) == 2
        captured = capsys.readouterr()
        assert captured.out == ""
        assert len(captured.err.strip().splitlines()) == 1 and "Traceback" not in captured.err


def test_cli_show_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["waveform", "show", str(PAPER), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    c, i = 1.0e-6, 0.55
    assert data["flyback_s"] == pytest.approx(200 / (i / c + 200 * 100))  # t_f ≈ C·ΔV/I
    assert data["rise_s"] + data["flyback_s"] == pytest.approx(0.01)
    assert data["stroke_m"] == pytest.approx(0.07e-6 * data["output_swing_v"])
    assert data["command_flyback_peak_slope_v_per_s"] is None  # a step: the current limit shapes it
    assert main(["waveform", "show", str(PAPER)]) == 0
    text = capsys.readouterr().out
    assert "None" not in text and "current limit makes the flyback" in text  # it printed Python's None


def test_cli_export_anc300_and_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["waveform", "export", str(PAPER), "--format", "anc300", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    up, down = load_waveform(PAPER).anc300_tables()
    assert data["up"] == up and data["down"] == down
    assert main(["waveform", "export", str(PAPER), "--format", "anc300"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:2] == ["setpu", "1"] and len(lines[0].split()) == 258
    out = tmp_path / "table.csv"
    assert (
        main(["waveform", "export", str(PAPER), "--format", "csv", "--points", "64", "--out", str(out)]) == 0
    )
    rows = out.read_text().splitlines()
    assert len(rows) == 65 and rows[0].startswith("phase,")
    assert not list(tmp_path.glob("*.tmp"))
    last = rows[-1].split(",")
    assert float(last[2]) == pytest.approx(200 * 63 / 64)


def test_an_output_that_is_an_input_or_another_output_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`waveform export F.toml --format csv --out F.toml` replaced the design file with its CSV."""
    design = tmp_path / "F.toml"
    design.write_text(PAPER.read_text())
    assert main(["waveform", "export", str(design), "--format", "csv", "--out", str(design)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out:" in err and "read by this command" in err
    assert design.read_text() == PAPER.read_text()
    same = tmp_path / "sub" / ".." / "F.toml"  # the same file by another name
    (tmp_path / "sub").mkdir()
    assert main(["waveform", "show", str(design), "--plot", str(same)]) == 2
    assert "--plot:" in capsys.readouterr().err and design.read_text() == PAPER.read_text()
    out = tmp_path / "x.png"
    assert main(["simulate", "--part", "300x300x50", "--ideal", "--periods", "2", "--map", str(out),
                 "--plot", str(out)]) == 2  # fmt: skip
    assert "another output" in capsys.readouterr().err and not out.exists()
    assert main(["waveform", "export", str(design), "--format", "csv", "--out", str(tmp_path / "F.csv")]) == 0


def test_a_plot_is_written_in_the_format_its_suffix_names(tmp_path: Path) -> None:
    """`--plot m.pdf` wrote PNG bytes into a .pdf file; an unknown suffix still gets a PNG."""
    pytest.importorskip("matplotlib")
    cases = (("w.pdf", b"%PDF"), ("w.svg", b"<?xml"), ("w.png", b"\x89PNG"), ("w.plot", b"\x89PNG"))
    for name, magic in cases:
        assert main(["waveform", "show", str(PAPER), "--plot", str(tmp_path / name)]) == 0
        assert (tmp_path / name).read_bytes().startswith(magic), name
