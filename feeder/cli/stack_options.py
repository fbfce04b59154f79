"""The ``--stack-*`` options: the piezo stacks a waveform is planned or designed for (the
daemon's ``[stack]``; :class:`feeder.plant.stack.StackParameters`)."""

from __future__ import annotations

import argparse

from feeder.cli.arguments import float_in
from feeder.plant.stack import STACK_RANGES, StackParameters

_STACK_OPTIONS = {
    "gain_m_per_v": ("m/V", "free stroke per volt"),
    "capacitance_f": ("F", "capacitance: with the current limit it sets the flyback, t_f ≈ C·ΔV/I_max"),
    "resonance_hz": ("Hz", "first axial resonance, loaded by the plate"),
    "damping_ratio": ("", "damping ratio of that resonance"),
    "output_resistance_ohm": ("Ω", "the amplifier's output resistance into the stack"),
}
"""Each option's field, unit and meaning."""


def add_stack_arguments(p: argparse.ArgumentParser) -> None:
    """``--stack-gain-m-per-v`` … ``--stack-output-resistance-ohm``, each within STACK_RANGES."""
    default = StackParameters()
    for field, (unit, what) in _STACK_OPTIONS.items():
        low, high = STACK_RANGES[field]
        p.add_argument(
            "--stack-" + field.replace("_", "-"),
            type=float_in(low, high),
            metavar="X",
            help=f"the stacks' {what}, {low:g}–{high:g}{' ' + unit if unit else ''} "
            f"(default {getattr(default, field):g}, firmware_sim's)",
        )


def stack_from(args: argparse.Namespace) -> StackParameters:
    """The stacks the options give (the others: the defaults, firmware_sim's)."""
    given = {field: getattr(args, "stack_" + field) for field in _STACK_OPTIONS}
    return StackParameters(**{k: v for k, v in given.items() if v is not None})
