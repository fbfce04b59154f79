"""The daemon's ``[stack]``: the stacks the waveforms are planned for, told to the simulated rig,
and the gain the camera calibration moves by."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from feeder.cli import main
from feeder.daemon.config import DaemonConfig
from feeder.daemon.config_file import load_config
from feeder.daemon.links import simulator_args
from feeder.daemon.step_modes import plan_step_modes
from feeder.errors import InputError
from feeder.parts import Part
from feeder.planner import plan
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.stack import StackParameters
from feeder.surface.parameters import DEFAULT_SURFACE
from feeder.waveform import read_waveform_tables
from firmware_sim.options import build_parser

WAVEFORMS = Path(__file__).resolve().parents[1] / "waveforms"

HARDWARE = '[amplifier]\nport = "/dev/ttyUSB0"\n'
BIG_STACK = "[stack]\ngain_m_per_v = 0.05e-6\ncapacitance_f = 2.0e-6\nresonance_hz = 20e3\n"


def _load(tmp_path: Path, text: str) -> DaemonConfig:
    path = tmp_path / "feeder.toml"
    path.write_text(text)
    return load_config(path)


def test_the_stack_section_gives_the_stacks_and_keeps_the_other_fields_default(tmp_path: Path) -> None:
    config = _load(tmp_path, BIG_STACK)
    assert config.stack == StackParameters(gain_m_per_v=0.05e-6, capacitance_f=2.0e-6, resonance_hz=20e3)
    assert config.planning_stack == config.stack
    assert _load(tmp_path, "").stack is None
    assert _load(tmp_path, "").planning_stack == StackParameters()


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("[stack]\ncapacitance = 1e-6\n", "unknown key stack.capacitance; did you mean stack.capacitance_f?"),
        ("[stack]\ncapacitance_f = 0.0\n", "stack.capacitance_f must be positive"),
        ("[stack]\ncapacitance_f = 1.0\n", "stack.capacitance_f = 1 is outside [1e-12, 0.001]"),
        ("[stack]\ngain_m_per_v = 'big'\n", "stack.gain_m_per_v must be a finite number"),
        ("[stack]\nresonance_hz = nan\n", "stack.resonance_hz must be a finite number"),
        ("[stack]\ndamping_ratio = 20.0\n", "stack.damping_ratio = 20 is outside"),
        ("[stack]\noutput_resistance_ohm = -1.0\n", "stack.output_resistance_ohm = -1 is outside"),
        ("stack = 5\n", "[stack] must be a table"),
    ],
)
def test_bad_stack_values_are_refused_by_name(tmp_path: Path, text: str, words: str) -> None:
    with pytest.raises(InputError) as err:
        _load(tmp_path, text)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_no_output_resistance_is_a_stack_too(tmp_path: Path) -> None:
    assert _load(tmp_path, "[stack]\noutput_resistance_ohm = 0.0\n").planning_stack.output_resistance_ohm == 0


def test_the_waveforms_are_planned_for_the_stated_stacks(tmp_path: Path) -> None:
    """A 2 µF stack takes twice as long to swing back at the same current: the daemon's coarse and
    fine waveforms are the planner's for that stack, not for firmware_sim's 1 µF."""
    stated = _load(tmp_path, BIG_STACK)
    modes = plan_step_modes(stated, DEFAULT_SURFACE)
    default = plan_step_modes(_load(tmp_path, ""), DEFAULT_SURFACE)
    limits = stated.amplifier.limits
    for name, distance in (("coarse", 1e-3), ("fine", stated.loop.tolerance_m)):
        expected = plan(
            stated.part,
            amplifier=limits,
            distance_m=distance,
            stack=stated.stack,
            frequency_hz=modes["coarse"].settings.frequency_hz,
        )
        assert modes[name].settings.amplitude_v == pytest.approx(expected.amplitude_vpp, rel=1e-12)
        assert modes[name].predicted_step_m == pytest.approx(abs(expected.predicted_step_m), rel=1e-12)
    assert modes["coarse"].predicted_step_m != pytest.approx(default["coarse"].predicted_step_m, rel=1e-3)


def test_the_embedded_simulator_gets_the_stated_stacks_and_firmware_sim_reads_them(tmp_path: Path) -> None:
    args = simulator_args(_load(tmp_path, BIG_STACK))
    parsed = build_parser().parse_args(args)
    assert parsed.load_capacitance_f == 2.0e-6
    assert (parsed.stack_gain_m_per_v, parsed.stack_resonance_hz) == (0.05e-6, 20e3)
    assert (parsed.stack_damping_ratio, parsed.stack_output_resistance_ohm) == (0.1, 8.0)
    defaults = build_parser().parse_args(simulator_args(_load(tmp_path, "")))
    stack = StackParameters()
    assert "--stack-gain-m-per-v" not in simulator_args(_load(tmp_path, ""))
    assert (defaults.load_capacitance_f, defaults.stack_gain_m_per_v) == (
        stack.capacitance_f,
        stack.gain_m_per_v,
    )


def test_hardware_without_a_stack_is_warned_about_and_its_gain_unknown(tmp_path: Path) -> None:
    bare = _load(tmp_path, HARDWARE)
    assert bare.stack_warning is not None and "no [stack]" in bare.stack_warning
    assert "1 µF" in bare.stack_warning
    assert bare.stack_gain_m_per_v is None  # the camera calibration must be told
    stated = _load(tmp_path, HARDWARE + BIG_STACK)
    assert (stated.stack_warning, stated.stack_gain_m_per_v) == (None, 0.05e-6)
    simulated = _load(tmp_path, "")
    assert (simulated.stack_warning, simulated.stack_gain_m_per_v) == (None, StackParameters().gain_m_per_v)
    assert dataclasses.replace(simulated, stack=stated.stack).stack_gain_m_per_v == 0.05e-6


def test_feeder_plan_plans_for_the_stacks_given_and_its_design_file_carries_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``feeder plan --stack-*`` plans as the planner does for those stacks; the design file it
    writes names them in ``[stack]``, and ``waveform show`` and ``simulate`` use them (they used
    firmware_sim's 1 µF whatever the file said)."""
    design = tmp_path / "plan.toml"
    args = ["plan", "--part", "300x300x50", "--distance-m", "100e-6", "--json"]
    assert (
        main([*args, "--stack-capacitance-f", "2e-6", "--stack-gain-m-per-v", "5e-8", "--out", str(design)])
        == 0
    )
    planned = json.loads(capsys.readouterr().out)
    stack = StackParameters(gain_m_per_v=5e-8, capacitance_f=2e-6)
    expected = plan(Part.parse("300x300x50"), distance_m=100e-6, stack=stack)
    assert planned["amplitude_vpp"] == pytest.approx(expected.amplitude_vpp, rel=1e-12)
    assert planned["predicted_step_m"] == pytest.approx(expected.predicted_step_m, rel=1e-12)
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["predicted_step_m"] > 1.5 * planned["predicted_step_m"]
    assert read_waveform_tables(design)["stack"] == dataclasses.asdict(stack)

    assert main(["waveform", "show", str(design), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    flyback, fraction = AmplifierLimits().current_limited_flyback(
        planned["amplitude_vpp"], planned["frequency_hz"], 2e-6
    )
    assert shown["flyback_s"] == pytest.approx(float(flyback), rel=1e-12)
    assert shown["stroke_m"] == pytest.approx(5e-8 * float(fraction) * planned["amplitude_vpp"], rel=1e-12)

    assert (
        main(["simulate", "--part", "300x300x50", "--waveform", str(design), "--periods", "6", "--json"]) == 0
    )
    simulated = json.loads(capsys.readouterr().out)
    assert simulated["step_mean_m"] == pytest.approx(planned["predicted_step_m"], rel=0.02)


def test_a_design_files_bad_stack_is_refused_by_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = WAVEFORMS / "paper-100hz-200vpp.toml"
    for table, words in (
        ("[stack]\ncapacitance_f = 2.0\n", "[stack].capacitance_f: 2 is outside [1e-12, 0.001]"),
        ("[stack]\ncapacitence_f = 2e-6\n", "[stack].capacitence_f: unknown field"),
        ("[stack]\ngain_m_per_v = 'x'\n", "[stack].gain_m_per_v: must be a number"),
    ):
        bad = tmp_path / "bad.toml"
        bad.write_text(good.read_text() + "\n" + table)
        assert main(["waveform", "show", str(bad)]) == 2
        error = capsys.readouterr().err
        assert words in error and error.count("\n") == 1
