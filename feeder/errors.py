"""The one root of every error the package raises on purpose: :class:`FeederError`.

Catch ``FeederError`` to handle anything this package reports; the subclasses
say what kind of trouble it is.  Drivers add theirs (``AmplifierError``,
``SensorLost``) under the same root.  Talking to the daemon (:class:`DaemonError`):

- :class:`DaemonRefused` (exit 1): the daemon said no, with its reason;
- :class:`MoveFailed` (exit 1), :class:`MoveFaulted`: the move ran and did not end ``done``;
- :class:`DaemonUnreachable` (exit 3), :class:`DaemonTimeout`: nobody answers in time.

:class:`InputError` is exit code 2.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from feeder.daemon.replies import MoveResult


SHOWN_CHARS = 160
"""The longest text a one-line error quotes whole (:func:`shown`)."""


def shown(text: str, limit: int = SHOWN_CHARS) -> str:
    """``text`` quoted for a one-line error: whole up to ``limit`` characters, else its start and
    its end around "…", so a long path keeps its file name and a pasted blob cannot flood the line."""
    if len(text) > limit:
        text = f"{text[: limit // 2 - 1]}…{text[-(limit // 2) :]}"
    return repr(text)


class FeederError(Exception):
    """Base of every error this package raises on purpose."""


class InputError(FeederError, ValueError):
    """Bad user input: names the field (or file) and says what is wrong.

    ``str(err)`` is the one line the CLI prints, e.g. ``--part: expected LxWxT in µm``.
    """

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


class DaemonError(FeederError):
    """Something about a request to the control daemon (see :mod:`feeder.daemon.client`)."""


class DaemonRefused(DaemonError):
    """The daemon refused the request; ``reason`` is its own words.

    ``result`` is the job's result when a queued move was refused later (by a stop, a
    fault or a shutdown), else None.  CLI exit code 1.
    """

    def __init__(self, reason: str, result: MoveResult | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.result = result


class MoveFailed(DaemonError):
    """A move or calibration ran and ended other than ``done`` (stopped, stalled, limit,
    oscillating, unreachable, fault); ``result`` says where the part is.  CLI exit code 1."""

    def __init__(self, result: MoveResult) -> None:
        super().__init__(f"{result.kind} {result.status}: {result.reason}")
        self.result = result


class MoveFaulted(MoveFailed):
    """A move ended with ``fault``: the amplifier or sensor link was lost (the daemon grounds
    the output and reconnects by itself)."""


class DaemonUnreachable(DaemonError):
    """No daemon answers on the socket: not running, wrong path, wrong owner, connection
    closed, or a reply that is not the daemon's protocol.  CLI exit code 3."""


class DaemonTimeout(DaemonUnreachable):
    """The daemon did not answer (a reply, an acknowledgement or a heartbeat) within
    ``timeout_s``: stopped, hung or overloaded.  CLI exit code 3."""

    def __init__(self, message: str, timeout_s: float) -> None:
        super().__init__(message)
        self.timeout_s = timeout_s


MEMORY_BUDGET_BYTES = 2 * 2**30
"""The memory a single command may ask for (2 GiB); larger sizes are refused up front."""


def check_memory_budget(field: str, nbytes: float) -> None:
    """Refuse (InputError naming ``field``) a request that needs more than :data:`MEMORY_BUDGET_BYTES`."""
    if not nbytes <= MEMORY_BUDGET_BYTES:
        raise InputError(
            field,
            f"needs ~{nbytes / 2**30:.3g} GiB, more than the "
            f"{MEMORY_BUDGET_BYTES // 2**30} GiB memory budget",
        )
