"""The plant's stack and contact stepped several times per DAC sample (``oversample``)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from feeder.cli import main
from feeder.errors import InputError
from feeder.plant import kernels
from feeder.plant.amplifier import AmplifierLimits, OutputStage
from feeder.plant.plant import Plant, run_waveform
from feeder.plant.stack import StackParameters
from feeder.plant.stick_slip import Friction
from feeder.waveform import Waveform

PAPER = Path(__file__).resolve().parents[1] / "waveforms" / "paper-100hz-200vpp.toml"
FRICTION = Friction(105.2519, 0.8)
UNLIMITED = AmplifierLimits(slew_rate_v_per_s=1e15, current_limit_a=1e15)


@pytest.fixture(params=[False, True], ids=["numpy", "compiled"])
def path(request: pytest.FixtureRequest) -> Iterator[bool]:
    if request.param and not kernels.AVAILABLE:
        pytest.skip("numba (extra 'fast') not installed")
    before = kernels.enabled()
    kernels.use_compiled(request.param)
    yield request.param
    kernels.use_compiled(before)


def test_oversampled_plant_is_a_finer_plant_on_the_amplifiers_piecewise_linear_voltage(path: bool) -> None:
    """Plant(oversample=N) streamed in uneven chunks equals, at every DAC sample, a plant N times
    faster (amplifier unlimited) fed the DAC-rate output stage's voltage interpolated linearly."""
    n, rate = 8, 100e3
    waveform = Waveform()
    index = np.arange(1, 3001)
    command = waveform.voltage_at_phase((index % 1000) / 1000)
    plant = Plant(FRICTION, oversample=n)
    part = np.concatenate([plant.advance(chunk) for chunk in np.split(command, [7, 1500, 1501])])
    voltage = OutputStage(AmplifierLimits(), StackParameters().capacitance_f, rate).advance(command)
    fine_time = np.arange(1, index.size * n + 1) / n
    fine = np.interp(fine_time, np.arange(index.size + 1), np.concatenate([[0.0], voltage]))
    reference = Plant(FRICTION, UNLIMITED, sample_rate_hz=rate * n).advance(fine)[n - 1 :: n]
    np.testing.assert_allclose(part, reference, rtol=0, atol=1e-15)
    assert np.ptp(part) > 5e-6  # it stepped
    assert plant.elapsed_s == pytest.approx(index.size / rate, rel=1e-12)
    assert plant.output_voltage_v == voltage[-1]


def test_the_paper_waveform_converges_and_the_dac_rate_error_is_the_documented_2_percent() -> None:
    """The stack rings at 30 kHz, 3.3 DAC samples per period: held between samples, the paper's
    waveform steps 2.1 % further than converged (plant.py's docstring, docs/plant.md)."""
    step = {n: run_waveform(FRICTION, Waveform(), 4, oversample=n).steps_m[-1] for n in (1, 20, 40)}
    assert step[20] == pytest.approx(step[40], rel=2e-4)
    assert step[40] == pytest.approx(3.2305e-6, rel=2e-4)
    assert step[1] / step[40] - 1 == pytest.approx(0.021, abs=0.001)


@pytest.mark.parametrize("bad", [0, 65, 2.0, True])
def test_oversample_out_of_range_is_refused(bad: object) -> None:
    with pytest.raises(InputError, match=r"^oversample: must be an integer in \[1, 64\]"):
        Plant(FRICTION, oversample=bad)  # type: ignore[arg-type]


def test_simulate_oversample_option(capsys: pytest.CaptureFixture[str]) -> None:
    base = ["simulate", "--part", "500x500x50", "--waveform", str(PAPER), "--periods", "3", "--json"]
    assert main([*base, "--oversample", "20"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["oversample"] == 20
    assert data["step_mean_m"] == pytest.approx(3.2307e-6, rel=2e-4)
    assert main(["simulate", "--part", "500x500x50", "--ideal", "--oversample", "2"]) == 2
    assert "--oversample: only for the plant on axis x or y" in capsys.readouterr().err
