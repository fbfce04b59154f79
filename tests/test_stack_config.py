"""The daemon's ``[stack]``: the stacks the waveforms are planned for, told to the simulated rig,
and the gain the camera calibration moves by."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from feeder.daemon.config import DaemonConfig
from feeder.daemon.config_file import load_config
from feeder.daemon.links import simulator_args
from feeder.daemon.step_modes import plan_step_modes
from feeder.errors import InputError
from feeder.planner import plan
from feeder.plant.stack import StackParameters
from feeder.surface.parameters import DEFAULT_SURFACE
from firmware_sim.options import build_parser

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
