"""The plant: amplifier limits, stack model, calibration to the paper, streaming state."""

from __future__ import annotations

import json
from pathlib import Path

import control
import numpy as np
import pytest

from feeder.cli import main
from feeder.contact.breakaway import contact
from feeder.paper import STEP_500_M
from feeder.parts import Part
from feeder.plant.amplifier import AmplifierLimits, OutputStage
from feeder.plant.ideal_plate import linear_flyback_step
from feeder.plant.plant import Plant, run_waveform
from feeder.plant.stack import StackFilter, StackParameters
from feeder.plant.stick_slip import Friction
from feeder.waveform import Waveform, load_waveform

REPO = Path(__file__).resolve().parents[1]
PAPER = REPO / "waveforms" / "paper-100hz-200vpp.toml"


def slope_limited_reference(u: np.ndarray, y0: float, d: float, lo: float, hi: float) -> np.ndarray:
    """Per-sample loop: y_k = clip(u_k, y_{k−1} − d, y_{k−1} + d) after the rails."""
    out, y = np.empty(u.size), y0
    for k, v in enumerate(np.clip(u, lo, hi)):
        y = min(max(v, y - d), y + d)
        out[k] = y
    return out


def test_output_stage_matches_per_sample_loop_in_any_chunking() -> None:
    rng = np.random.default_rng(2)
    limits = AmplifierLimits(v_min_v=-10, v_max_v=150, current_limit_a=0.3)
    u = np.cumsum(rng.normal(0, 1.0, 5000)) + np.where(rng.random(5000) < 0.01, 120.0, 0.0)
    stage = OutputStage(limits, 1e-6, 100e3)
    d = stage.max_step_v
    assert d == pytest.approx(0.3 / 1e-6 / 100e3)
    reference = slope_limited_reference(u, 0.0, d, -10, 150)
    cuts = np.sort(rng.choice(np.arange(1, 5000), 60, replace=False))
    got = np.concatenate([stage.advance(c) for c in np.split(u, cuts)])
    np.testing.assert_allclose(got, reference, rtol=0, atol=1e-9)


def test_current_limited_flyback_time() -> None:
    """A dropping command falls at I/C and meets the rising command after ΔV/(I/C + ΔV·f)."""
    amp = AmplifierLimits()
    w = Waveform(frequency_hz=100, amplitude_vpp=200)
    stage = OutputStage(amp, 1e-6, 1e6, initial_v=0.0)
    per = 10_000
    index = np.arange(1, 2 * per + 1)
    out = stage.advance(w.voltage_at_phase((index % per) / per))
    falling = np.flatnonzero(np.diff(out[: per + per // 2]) < -1e-9)  # the first flyback only
    assert np.all(np.diff(falling) == 1)
    measured = falling.size / 1e6
    t_f, fraction = amp.current_limited_flyback(200, 100, 1e-6)
    assert measured == pytest.approx(float(t_f), abs=2e-6)
    assert float(t_f) == pytest.approx(200 / (0.55 / 1e-6 + 200 * 100))
    assert out[per:].min() == pytest.approx(200 * (1 - float(fraction)), abs=0.1)


def test_stack_model_gain_resonance_and_velocity_output() -> None:
    stack = StackParameters()
    tf = stack.position_model()
    assert control.dcgain(tf) == pytest.approx(0.07e-6)
    w_n = 2 * np.pi * stack.resonance_hz
    poles = control.poles(tf)
    assert np.max(np.abs(poles.imag)) == pytest.approx(w_n * np.sqrt(1 - 0.1**2), rel=1e-9)
    rate = 100e3
    filt = StackFilter(stack, rate, initial_v=50.0)
    x, v = filt.advance(np.full(100, 50.0))
    np.testing.assert_allclose(x, 50 * 0.07e-6, rtol=1e-8)  # starts at rest, stays there
    ramp = 50.0 + 1e4 * np.arange(1, 3001) / rate  # 10 kV/s ramp
    x, v = filt.advance(ramp)
    assert v[-1] == pytest.approx(0.07e-6 * 1e4, rel=1e-6)  # follows at g·dV/dt
    np.testing.assert_allclose(np.diff(x[-500:]) * rate, 0.5 * (v[-500:-1] + v[-499:]), rtol=1e-6)


def paper_friction(label: str = "500x500x50") -> Friction:
    return Friction(contact(Part.parse(label)).breakaway_accel_m_s2)


def test_paper_waveform_gives_3_3_um_per_step() -> None:
    run = run_waveform(paper_friction(), load_waveform(PAPER), 5)
    assert np.all(np.abs(run.steps_m - STEP_500_M) <= 0.2e-6)
    assert run.steps_m.std() < 1e-12
    assert run.net_displacement_m == pytest.approx(run.steps_m.sum())
    assert 0 < run.slip_fraction < 0.2


def test_step_does_not_depend_on_part_size_on_flat_support() -> None:
    steps = [
        run_waveform(paper_friction(p), load_waveform(PAPER), 2).steps_m[-1]
        for p in ("80x80x50", "100x100x50", "200x200x50", "300x300x50", "500x500x50")
    ]
    np.testing.assert_allclose(steps, steps[0], rtol=1e-9)


def test_fast_stiff_stack_approaches_the_ideal_closed_form() -> None:
    """Stiff stack, no output resistance: the plant reduces to the current-limited ideal sawtooth."""
    stiff = StackParameters(resonance_hz=2e6, damping_ratio=0.7, output_resistance_ohm=0.0)
    amp = AmplifierLimits()
    run = run_waveform(paper_friction(), load_waveform(PAPER), 2, stack=stiff, sample_rate_hz=2e6)
    t_f, fraction = amp.current_limited_flyback(200, 100, stiff.capacitance_f)
    ideal = linear_flyback_step(
        0.07e-6 * 200 * fraction, 0.01 - t_f, t_f, 0.8 * paper_friction().static_accel_m_s2
    )
    assert run.steps_m[-1] == pytest.approx(float(ideal), rel=3e-3)


def test_streaming_chunks_equal_one_call_and_backward_moves_back() -> None:
    w = load_waveform(PAPER)
    per = 1000
    index = np.arange(1, 5 * per + 1)
    command = w.voltage_at_phase((index % per) / per)
    one = Plant(paper_friction()).advance(command)
    chunked = Plant(paper_friction())
    got = np.concatenate([chunked.advance(c) for c in np.split(command, 50)])
    np.testing.assert_allclose(got, one, rtol=0, atol=1e-15)
    assert chunked.part_position_m == pytest.approx(one[-1], abs=1e-15)
    back = Waveform(frequency_hz=100, amplitude_vpp=200, direction="backward")
    assert run_waveform(paper_friction(), back, 2).steps_m[-1] < -3e-6


def test_from_contact_and_scatter() -> None:
    part = Part.parse("300x300x50")
    plant = Plant.from_contact(part, tau_pa=15e9, scatter=0.1, seed=4)
    assert plant.contact.friction.static_accel_m_s2 == pytest.approx(
        contact(part, tau_pa=15e9).breakaway_accel_m_s2
    )
    w = load_waveform(PAPER)
    a = run_waveform(paper_friction(), w, 20, scatter=0.1, seed=4).steps_m
    b = run_waveform(paper_friction(), w, 20, scatter=0.1, seed=4).steps_m
    np.testing.assert_array_equal(a, b)
    assert 1e-8 < a.std() < 2e-6


def test_low_amplitude_smooth_command_does_not_move_the_part() -> None:
    """A 100 Hz, 90 Vpp cosine starting at rest: |a_plate| ≈ 1.5 m/s² ≪ a_break, no slip at all."""
    plant = Plant(paper_friction(), initial_v=100.0)
    t = np.arange(1, 20001) / 100e3
    part, plate = plant.advance_traces(100 - 45 * (1 - np.cos(2 * np.pi * 100 * t)))
    assert np.max(np.abs(part - plate)) == 0.0
    assert plant.slip_time_s == 0.0


def test_cli_simulate_paper_and_ideal(capsys: pytest.CaptureFixture[str]) -> None:
    assert (
        main(["simulate", "--part", "500x500x50", "--waveform", str(PAPER), "--periods", "10", "--json"]) == 0
    )
    data = json.loads(capsys.readouterr().out)
    assert data.keys() >= {"step_mean_m", "step_std_m", "net_displacement_m", "periods", "slip_fraction"}
    assert data["step_mean_m"] == pytest.approx(STEP_500_M, abs=0.2e-6)
    assert data["periods"] == 10
    assert (
        main(
            [
                "simulate",
                "--part",
                "300x300x50",
                "--ideal",
                "--stroke-m",
                "5e-6",
                "--frequency-hz",
                "100",
                "--flyback-s",
                "1e-4",
                "--flyback-shape",
                "linear",
                "--kinetic-ratio",
                "0.8",
                "--periods",
                "20",
                "--json",
            ]
        )
        == 0
    )
    data = json.loads(capsys.readouterr().out)
    a_k = 0.8 * data["breakaway_accel_m_s2"]
    expected = 5e-6 * (1 + 1e-4 / 9.9e-3) - a_k * 1e-8
    assert data["step_mean_m"] == pytest.approx(expected, rel=1e-9)
    assert data["net_displacement_m"] == pytest.approx(20 * expected, rel=1e-9)


def test_cli_simulate_bad_input(capsys: pytest.CaptureFixture[str]) -> None:
    assert (
        main(
            [
                "simulate",
                "--part",
                "300x300x50",
                "--ideal",
                "--stroke-m",
                "5e-6",
                "--frequency-hz",
                "100",
                "--flyback-s",
                "0.02",
                "--json",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "--flyback-s" in err and len(err.strip().splitlines()) == 1
