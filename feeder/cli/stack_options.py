"""The ``--stack-*`` options: the piezo stacks a waveform is planned or designed for (the
daemon's ``[stack]``; :class:`feeder.plant.stack.StackParameters`)."""

from __future__ import annotations

import argparse

from feeder.cli.arguments import float_in
from feeder.plant.stack import STACK_FIELDS, STACK_RANGES, StackParameters


def add_stack_arguments(p: argparse.ArgumentParser) -> None:
    """``--stack-gain-m-per-v`` … ``--stack-output-resistance-ohm``, each within STACK_RANGES."""
    default = StackParameters()
    for field, (unit, what) in STACK_FIELDS.items():
        low, high = STACK_RANGES[field]
        p.add_argument(
            "--stack-" + field.replace("_", "-"),
            type=float_in(low, high),
            metavar="X",
            help=f"{what}, {low:g}–{high:g}{' ' + unit if unit else ''} "
            f"(default {getattr(default, field):g}, firmware_sim's)",
        )


def stack_from(args: argparse.Namespace) -> StackParameters:
    """The stacks the options give (the others: the defaults, firmware_sim's)."""
    given = {field: getattr(args, "stack_" + field) for field in STACK_FIELDS}
    return StackParameters(**{k: v for k, v in given.items() if v is not None})
