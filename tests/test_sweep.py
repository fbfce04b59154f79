"""feeder sweep: spec parsing, physics of the rows, Dask = serial, resuming after an interruption."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pd = pytest.importorskip("pandas", reason="the sweep extra (pandas, pyarrow, dask) is not installed")
pytest.importorskip("pyarrow", reason="the sweep extra (pyarrow) is not installed")

from feeder.cli import main  # noqa: E402
from feeder.contact.breakaway import contact  # noqa: E402
from feeder.errors import InputError  # noqa: E402
from feeder.parts import Part  # noqa: E402
from feeder.plant.ideal_plate import linear_flyback_step  # noqa: E402
from feeder.plant.plant import run_waveform  # noqa: E402
from feeder.plant.stick_slip import Friction  # noqa: E402
from feeder.sweep import parts_dir, run_sweep  # noqa: E402
from feeder.sweep_spec import DEFAULTS, SweepSettings, load_spec  # noqa: E402
from feeder.waveform import Waveform  # noqa: E402

BIG = """
[sweep]
model = "ideal"
periods = 3
chunk_size = 96
[parameters]
frequency_hz = {min = 20.0, max = 1500.0, num = 12, log = true}
amplitude_vpp = {min = 20.0, max = 200.0, num = 14}
flyback_shape = ["current-limited", "linear"]
flyback_s = [1e-4, 3e-4, 8e-4]
part = ["300x300x50", "500x500x50"]
"""


def write(tmp_path: Path, text: str, name: str = "spec.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def serial_big(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(spec, result) of the 2016-point sweep run serially, shared by the tests below."""
    folder = tmp_path_factory.mktemp("serial")
    spec = write(folder, BIG)
    out = folder / "serial.parquet"
    run_sweep(load_spec(spec), out, serial=True)
    return spec, out


def test_ideal_rows_match_the_closed_form(serial_big):
    spec = load_spec(serial_big[0])
    assert len(spec.points) == 12 * 14 * 2 * 3 * 2 == 2016
    frame = pd.read_parquet(serial_big[1])
    assert list(frame["point"]) == list(range(2016))
    for column in (
        "frequency_hz",
        "amplitude_vpp",
        "flyback_shape",
        "flyback_s",
        "part",
        "support",
        "surface",
        "tau_pa",
        "kinetic_ratio",
        "scatter",
        "seed",
    ):
        assert column in frame.columns
    linear = frame[(frame["flyback_shape"] == "linear") & (frame["error"] == "")]
    rise = 1 / linear["frequency_hz"] - linear["flyback_s"]
    ok = linear[linear["flyback_s"] <= rise]
    a_k = 0.8 * ok["breakaway_accel_m_s2"]
    closed = linear_flyback_step(0.07e-6 * ok["amplitude_vpp"], 1 / ok["frequency_hz"] - ok["flyback_s"],
                                 ok["flyback_s"], a_k)  # fmt: skip
    np.testing.assert_allclose(ok["step_mean_m"], closed, rtol=1e-9, atol=1e-15)
    assert (ok["step_mean_m"] > 0).sum() > 100  # the comparison covers moving points
    # 0.8 ms flyback at 1500 Hz is longer than the period: an error row, not a crash
    assert (frame["error"] != "").sum() > 0
    assert frame.loc[frame["error"] != "", "step_mean_m"].isna().all()


def test_plant_rows_are_the_plant_model_with_their_seed(tmp_path):
    spec = load_spec(
        write(
            tmp_path,
            """
[sweep]
periods = 4
chunk_size = 2
[parameters]
frequency_hz = [100.0]
amplitude_vpp = [150.0]
part = ["300x300x50"]
scatter = [0.05]
seed = [1, 2, 3]
""",
        )
    )
    out = tmp_path / "p.parquet"
    run_sweep(spec, out, serial=True)
    frame = pd.read_parquet(out)
    a_s = contact(Part.parse("300x300x50")).breakaway_accel_m_s2
    for _, row in frame.iterrows():
        run = run_waveform(Friction(a_s), Waveform(100.0, 150.0), 4, scatter=0.05, seed=int(row["seed"]))
        assert row["step_mean_m"] == np.mean(run.steps_m)
        assert row["step_std_m"] == np.std(run.steps_m, ddof=1)
    assert frame["step_mean_m"].nunique() == 3  # different seeds, different scatter


def test_interrupted_sweep_recomputes_nothing_finished(tmp_path, serial_big):
    spec = load_spec(serial_big[0])
    reference = serial_big[1]
    out = tmp_path / "r.parquet"

    def stop_after_five(done: int, total: int, cached: int) -> None:
        if done == 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, out, serial=True, progress=stop_after_five)
    assert not out.exists()
    parts = sorted(parts_dir(out).glob("chunk-*.parquet"))
    assert len(parts) == 5
    stamps = {p: p.stat().st_mtime_ns for p in parts}
    report = run_sweep(spec, out, serial=True)
    assert (report.cached, report.computed) == (5, len(spec.chunks()) - 5)
    assert {p: p.stat().st_mtime_ns for p in parts} == stamps  # not rewritten
    pd.testing.assert_frame_equal(pd.read_parquet(out), pd.read_parquet(reference))
    again = run_sweep(spec, out, serial=True)
    assert again.computed == 0


def test_local_dask_cluster_matches_the_serial_run_exactly(tmp_path, capsys, serial_big):
    pytest.importorskip("distributed", reason="the sweep extra (dask[distributed]) is not installed")
    spec_path, serial = serial_big
    dask_out = tmp_path / "dask.parquet"
    assert main(["sweep", str(spec_path), "--out", str(dask_out), "--workers", "2", "--json"]) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out)
    assert report["points"] == 2016 and report["chunks_computed"] == 21
    assert "21/21 chunks" in captured.err  # progress on stderr
    pd.testing.assert_frame_equal(pd.read_parquet(dask_out), pd.read_parquet(serial), check_exact=True)


def test_bad_specs_name_the_field(tmp_path, capsys):
    cases = {
        "[sweep]\nmodel = 'fem'\n": "[sweep].model",
        "[parameters]\nfrequency = [1.0]\n": "[parameters].frequency",
        "[parameters]\nfrequency_hz = {min = 1.0, max = 2.0}\n": "[parameters].frequency_hz.num",
        "[parameters]\npart = ['300x300']\n": "[parameters].part",
        "[sweep]\nsample = 'random'\n": "[sweep].points",
    }
    for text, field in cases.items():
        with pytest.raises(InputError) as err:
            load_spec(write(tmp_path, text))
        assert field in err.value.field
    spec = write(tmp_path, "[parameters]\nfrequency_hz = [100.0]\n")
    assert main(["sweep", str(spec), "--out", str(tmp_path / "x.csv")]) == 2
    assert "--out" in capsys.readouterr().err


def test_random_sample_is_reproducible_and_inside_its_ranges(tmp_path):
    text = """
[sweep]
sample = "random"
points = 50
seed = 7
[parameters]
frequency_hz = {min = 50.0, max = 500.0, log = true}
amplitude_vpp = {min = 50.0, max = 200.0}
flyback_shape = ["current-limited", "linear"]
"""
    a = load_spec(write(tmp_path, text)).points
    b = load_spec(write(tmp_path, text)).points
    assert a == b
    f = np.array([p["frequency_hz"] for p in a])
    assert f.min() >= 50 and f.max() <= 500 and len(set(f)) == 50
    assert {p["flyback_shape"] for p in a} == {"current-limited", "linear"}


def test_the_contact_is_solved_once_per_input_not_per_chunk(monkeypatch):
    import feeder.sweep as sweep

    calls: list[str] = []

    def counting(part, *args, **kwargs):
        calls.append(part.label)
        return contact(part, *args, **kwargs)

    monkeypatch.setattr(sweep, "contact", counting)
    sweep.breakaway_accel_m_s2.cache_clear()
    rows = [{**DEFAULTS, "part": p, "amplitude_vpp": v} for p in ("300x300x50", "500x500x50")
            for v in (100.0, 150.0)]  # fmt: skip
    settings = SweepSettings(model="ideal", periods=2)
    frames = [sweep.evaluate_chunk(settings, rows[k : k + 1]) for k in range(4)]
    assert sorted(calls) == ["300x300x50", "500x500x50"]
    expected = contact(Part.parse("500x500x50"), tau_pa=DEFAULTS["tau_pa"]).breakaway_accel_m_s2
    assert frames[3]["breakaway_accel_m_s2"].iloc[0] == expected
    sweep.breakaway_accel_m_s2.cache_clear()


def test_local_workers_get_the_malloc_settings_before_they_start():
    """Dask's MALLOC_TRIM_THRESHOLD_=65536 costs ~+47 % CPU per chunk in page faults (feeder.sweep)."""
    import os

    from dask.distributed import Client

    from feeder.sweep import WORKER_MALLOC_ENV, local_cluster

    with local_cluster(1) as cluster, Client(cluster) as client:
        seen = client.run(lambda: {k: os.environ.get(k) for k in WORKER_MALLOC_ENV})
    assert list(seen.values()) == [{k: str(v) for k, v in WORKER_MALLOC_ENV.items()}]


class _GuardedNumpy:
    """numpy for feeder.sweep_spec whose grid ranges refuse to build a huge axis (old code would)."""

    def __getattr__(self, name: str):
        return getattr(np, name)

    @staticmethod
    def linspace(lo, hi, num):
        assert num <= 10**5, f"expanded a {num}-value axis before checking its size"
        return np.linspace(lo, hi, num)

    geomspace = linspace


@pytest.fixture
def no_work(monkeypatch):
    """Fail (instead of eating memory) if a sweep expands or evaluates before its size checks."""
    import itertools
    import types

    import feeder.sweep as sweep
    import feeder.sweep_spec as sweep_spec

    def product(*lists):
        size = int(np.prod([len(values) for values in lists]))
        assert size <= 10**5, f"expanded {size} grid points before checking the count"
        return itertools.product(*lists)

    def refuse(*args, **kwargs):
        raise AssertionError("work started before the size checks")

    monkeypatch.setattr(sweep_spec, "np", _GuardedNumpy())
    monkeypatch.setattr(sweep_spec, "itertools", types.SimpleNamespace(product=product))
    monkeypatch.setattr(sweep_spec, "_random_points", refuse)
    monkeypatch.setattr(sweep, "evaluate_chunk", refuse)


@pytest.mark.parametrize(
    ("text", "field", "words"),
    [
        ("[sweep]\nperiods = 1000000000\n", "[sweep].periods", "1–1000000"),
        ("[parameters]\nfrequency_hz = {min = 1.0, max = 1000.0, num = 100000000}\n",
         "[parameters].frequency_hz.num", "memory budget"),
        ("[sweep]\nsample = 'random'\npoints = 1000000000\n", "[sweep].points", "memory budget"),
        ("[parameters]\nfrequency_hz = {min = 1.0, max = 1000.0, num = 1000}\n"
         "amplitude_vpp = {min = 10.0, max = 200.0, num = 2000}\n",
         "[parameters]", "1000 frequency_hz × 2000 amplitude_vpp"),
        # 10^5 plant periods at 100 Hz: 10^10 samples
        ("[sweep]\nperiods = 100000\n[parameters]\nfrequency_hz = [100.0]\n", "[sweep].periods", "GiB"),
        # a frequency the amplifier refuses runs nothing: the costliest point is at its 1 Hz floor
        ("[sweep]\nperiods = 50000\n[parameters]\nfrequency_hz = [0.01, 100.0]\n", "[sweep].periods",
         "a 100 Hz plant point"),
        ("[sweep]\nmodel = 'ideal'\nperiods = 100000\n[parameters]\nflyback_shape = ['half-cosine']\n",
         "[sweep].periods", "ideal-model chunk"),
    ],
)  # fmt: skip
def test_oversized_sweeps_are_refused_before_any_work(tmp_path, capsys, no_work, text, field, words):
    spec = write(tmp_path, text)
    out = tmp_path / "big.parquet"
    assert main(["sweep", str(spec), "--out", str(out), "--serial"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("feeder sweep: error: ")
    assert f"{spec}: {field}: " in err and words in err
    assert sorted(tmp_path.iterdir()) == [spec]  # no result, no parts folder


def test_sizes_within_the_limits_still_load(tmp_path):
    from feeder.plant.plant import MAX_PERIODS

    ideal = load_spec(write(tmp_path, f"[sweep]\nmodel = 'ideal'\nperiods = {MAX_PERIODS}\n"))
    assert ideal.settings.periods == MAX_PERIODS and len(ideal.points) == 1
    # 3001 periods × 1000 samples at 100 Hz: ~0.2 GiB; 0.01 Hz is below the amplifier's range (unrun)
    text = "[sweep]\nperiods = 3000\n[parameters]\nfrequency_hz = [0.01, 100.0]\n"
    assert load_spec(write(tmp_path, text)).settings.periods == 3000


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_an_unreachable_scheduler_is_one_line_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed", reason="the sweep extra (dask[distributed]) is not installed")
    import time

    import feeder.sweep as sweep

    monkeypatch.setattr(sweep, "SCHEDULER_CONNECT_TIMEOUT_S", 0.5)
    spec = write(tmp_path, "[sweep]\nmodel = 'ideal'\n")
    out = tmp_path / "r.parquet"
    address = f"tcp://127.0.0.1:{_free_port()}"
    start = time.monotonic()
    assert main(["sweep", str(spec), "--out", str(out), "--scheduler", address]) == 3
    assert time.monotonic() - start < 10
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith(f"feeder sweep: scheduler unreachable: --scheduler {address}: ")
    assert sorted(tmp_path.iterdir()) == [spec]
    assert main(["sweep", str(spec), "--out", str(out), "--scheduler", "bogus://x"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("feeder sweep: error: --scheduler: 'bogus://x': ")
    assert sorted(tmp_path.iterdir()) == [spec]


def test_failed_points_are_counted_and_all_failed_exits_1(tmp_path, capsys):
    half = write(
        tmp_path, "[sweep]\nmodel = 'ideal'\n[parameters]\nfrequency_hz = [-5.0, 100.0]\n", "half.toml"
    )
    assert main(["sweep", str(half), "--out", str(tmp_path / "half.parquet"), "--serial"]) == 0
    assert "2 points in 1 chunk (1 computed, 0 already done), 1 failed → " in capsys.readouterr().out
    assert main(["sweep", str(half), "--out", str(tmp_path / "half.parquet"), "--serial", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["points_failed"], report["chunks_cached"]) == (1, 1)  # counted from the cached chunk
    assert report["first_error"].startswith("frequency_hz: ")

    text = "[sweep]\nmodel = 'ideal'\n[parameters]\nflyback_shape = ['linear']\nflyback_s = [0.02, 0.03]\n"
    bad = write(tmp_path, text, "bad.toml")
    out = tmp_path / "bad.parquet"
    assert main(["sweep", str(bad), "--out", str(out), "--serial", "--json"]) == 1
    captured = capsys.readouterr()
    report = json.loads(captured.out)
    assert report["points"] == report["points_failed"] == 2
    assert report["first_error"] == "flyback_s: 0.02 s is not shorter than the period 0.01 s"
    assert captured.err.strip().splitlines()[-1] == (
        "feeder sweep: failed: every point failed; the first: " + report["first_error"]
    )
    assert (pd.read_parquet(out)["error"] != "").all()  # the result file still says why, per point
