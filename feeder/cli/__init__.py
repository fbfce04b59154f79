"""The ``feeder`` command: one thin sub-command module per concept.

Each module named in :data:`SUBCOMMANDS` lives in this package and provides
``register(subparsers)``, which adds its parser and sets ``handler`` to a
function ``(args) -> int``.  Every sub-command takes ``--json``.
Bad input raises :class:`feeder.errors.InputError`; :func:`main` turns it into
one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import NoReturn

from feeder.errors import InputError

SUBCOMMANDS: tuple[str, ...] = (
    "contact", "surface", "friction", "tau", "figures", "control", "waveform", "simulate", "plan",
    "daemon", "demo", "sweep",
)


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line and exit code 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="feeder", description=__doc__.splitlines()[0] if __doc__ else None)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    for name in SUBCOMMANDS:
        importlib.import_module(f"feeder.cli.{name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args))
    except InputError as err:
        print(f"feeder {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"feeder {args.command}: interrupted", file=sys.stderr)
        return 130
