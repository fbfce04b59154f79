"""The ``feeder`` command: one thin sub-command module per concept.

:data:`COMMANDS` names each sub-command, the module of this package that
provides it and its one-line help.  A module provides ``register(subparsers)``,
which adds its parsers and sets ``handler`` to a function ``(args) -> int``.
Every sub-command takes ``--json``.

Start-up is lazy: :func:`main` imports only the module of the sub-command on
the command line (``feeder --help`` none; the others get a placeholder parser
with their help line), so ``feeder --help`` and ``feeder status`` never load
numpy or scipy.

Exit codes (:func:`main`): 0 done; 1 the daemon refused or the move failed
(:class:`~feeder.errors.DaemonRefused`, :class:`~feeder.errors.MoveFailed`, its
reason on stderr); 2 bad input (:class:`~feeder.errors.InputError`, one line
naming the field); 3 the daemon is unreachable or did not answer in time
(:class:`~feeder.errors.DaemonUnreachable`, :class:`~feeder.errors.DaemonTimeout`); 141 stdout
was closed by its reader (``| head``).
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
from collections.abc import Iterable, Sequence
from typing import Any, NoReturn

from feeder.cli.arguments import refuse_overwriting_inputs
from feeder.cli.output import exit_on_closed_stdout
from feeder.errors import DaemonRefused, DaemonUnreachable, FeederError, InputError, MoveFailed

#: sub-command → (module in this package, one-line help), in ``feeder --help`` order
COMMANDS: dict[str, tuple[str, str]] = {
    "contact": ("contact", "real contact area and breakaway force of a part"),
    "adhesion": ("adhesion", "single-asperity adhesion: Hertz, DMT, JKR, Maugis–Dugdale"),
    "surface": ("surface", "summit statistics of AFM scans, GW surface TOML"),
    "friction": ("friction", "static-friction peaks of force curves (CSV)"),
    "tau": ("tau", "shear strength τ = F/A_r from friction forces or force curves"),
    "figures": ("figures", "paper Fig. 9 and τ tables IV–VI, recomputed, as PNGs"),
    "move": ("control", "move the part to TARGET_M (or by --by DELTA_M)"),
    "status": ("control", "the daemon's state, position, learned steps"),
    "stop": ("control", "stop the running move (and drop queued ones)"),
    "calibrate": ("control", "learn the step sizes: bursts forward and back, both waveforms"),
    "history": ("control", "recorded moves, oldest first"),
    "release": ("control", "let held parts go: later moves of other parts no longer keep them (plane)"),
    "shutdown": ("control", "stop the daemon (it grounds the output first)"),
    "waveform": ("waveform", "show a waveform file or export its tables"),
    "simulate": ("simulate", "simulate a part stepping on the plate"),
    "plan": ("plan", "plan a move: waveform, steps, predicted step and band"),
    "daemon": ("daemon", "run the control daemon (no config: the simulated plane, x, y and θ)"),
    "state": ("state", "back up the daemon's state database (safe while it runs), or restore one"),
    "demo": ("demo", "closed-loop positioning on a simulated amplifier"),
    "vision": ("vision", "pose of parts from camera images, camera frames, calibration"),
    "sweep": ("sweep", "parameter sweep on Dask (local cluster or a scheduler), to Parquet"),
}


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line and exit code 2, and whose option
    values may start with a minus sign (``--pose -1e-3,0,0``, ``--load -1e-8``): argparse takes
    ``-1e-8`` for an option unless it looks like a plain negative number, and no option of
    ``feeder`` looks like a number, so any argument starting with ``-`` and a digit is a value."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-\.?\d")

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The ``feeder`` parser with the real parsers of ``commands`` (None: all of them);
    every other sub-command is a placeholder carrying only its help line."""
    wanted = (
        {COMMANDS[c][0] for c in COMMANDS}
        if commands is None
        else {COMMANDS[c][0] for c in commands if c in COMMANDS}
    )
    parser = OneLineParser(prog="feeder", description=__doc__.splitlines()[0] if __doc__ else None)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    registered: set[str] = set()
    for name, (module, help_line) in COMMANDS.items():
        if module not in wanted:
            sub.add_parser(name, help=help_line)
        elif module not in registered:
            importlib.import_module(f"feeder.cli.{module}").register(sub)
            registered.add(module)
    return parser


def _command_in(argv: Sequence[str]) -> list[str]:
    """The sub-command named on the command line: its first word not starting with ``-``
    (``feeder`` itself has no option taking a value)."""
    return [word for word in argv if not word.startswith("-")][:1]


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(_command_in(argv))
    args = parser.parse_args(argv)
    prefix = f"feeder {args.command}"
    try:
        refuse_overwriting_inputs(parser, args)
        code = int(args.handler(args))
        sys.stdout.flush()  # here, where a closed stdout can still be caught
        return code
    except BrokenPipeError:  # the reader went away (`feeder contact --table --json | head`)
        exit_on_closed_stdout()
    except InputError as err:
        print(f"{prefix}: error: {err}", file=sys.stderr)
        return 2
    except (DaemonRefused, MoveFailed) as err:
        print(
            f"{prefix}: refused: {err}" if isinstance(err, DaemonRefused) else f"{prefix}: failed: {err}",
            file=sys.stderr,
        )
        return 1
    except DaemonUnreachable as err:
        print(f"{prefix}: daemon unreachable: {err}", file=sys.stderr)
        return 3
    except FeederError as err:  # a device's: an amplifier's or camera's refusal, a lost link
        print(f"{prefix}: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{prefix}: interrupted", file=sys.stderr)
        return 130
