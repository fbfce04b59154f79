"""The ANC300 console contract as data: verbs, axis modes, fault bits (DESIGN §5).

:data:`VERBS` is the one verb table.  ``real`` marks the verbs an attocube
ANC300 understands (its manual's set); the others are firmware_sim extensions
for tests and diagnostics.  The host's move path uses only :data:`MOVE_PATH`,
a subset of the real set, so what the tests exercise is what runs on a real
unit; ``python -m firmware_sim --dialect anc300`` answers every other verb
with the ANC300's own error reply (:data:`UNKNOWN_COMMAND`).
Reference with the replies: docs/anc300-protocol.md.
"""

from __future__ import annotations

from dataclasses import dataclass

TCP_PORT = 7230
"""The ANC300's TCP console port."""
DEFAULT_PASSWORD = "123456"
"""The ANC300's factory console password."""
UNKNOWN_COMMAND = "Unknown command"
"""The error line an ANC300 answers a verb it does not know with (then ``ERROR``)."""
PATTERN_POINTS = 256
"""Points of a ``setpu``/``setpd`` waveform table."""
PATTERN_MAX = 255
"""Largest value of a waveform-table point (0 = bottom, 255 = top of the amplitude)."""

MODES = ("gnd", "inp", "cap", "stp", "off", "stp+", "stp-")
"""Axis modes (``setm``/``getm``)."""
STEPPING_MODES = ("stp", "stp+", "stp-")
"""Modes in which ``stepu``/``stepd`` move the axis."""

FAULT_BITS: dict[str, int] = {"watchdog": 0x01, "host_watchdog": 0x02, "overtemp": 0x04}
"""Bits of an axis' latched fault word (firmware_sim and the CANopen node; 0 = healthy).
A real ANC300 reports none: its host sees faults as errors and lost links."""

DIALECTS = ("anc300", "extended")
"""firmware_sim console dialects: the real set only, or the real set plus extensions."""


@dataclass(frozen=True)
class Verb:
    """One console verb: its usage after the verb, whether it takes an axis, and
    whether a real ANC300 has it."""

    name: str
    usage: str
    real: bool
    axis: bool = True


VERBS: tuple[Verb, ...] = (
    Verb("echo", "on|off", True, axis=False),
    Verb("ver", "", True, axis=False),
    Verb("help", "", True, axis=False),
    Verb("getcser", "", True, axis=False),
    Verb("getser", "AXIS", True),
    Verb("setm", "AXIS gnd|inp|cap|stp|off|stp+|stp-", True),
    Verb("getm", "AXIS", True),
    Verb("setf", "AXIS HZ", True),
    Verb("getf", "AXIS", True),
    Verb("setv", "AXIS VOLTS", True),
    Verb("getv", "AXIS", True),
    Verb("seta", "AXIS VOLTS", True),
    Verb("geta", "AXIS", True),
    Verb("geto", "AXIS", True),
    Verb("stepu", "AXIS [N|c]", True),
    Verb("stepd", "AXIS [N|c]", True),
    Verb("stop", "AXIS", True),
    Verb("stepw", "AXIS", True),
    Verb("getc", "AXIS", True),
    Verb("capw", "AXIS", True),
    Verb("setpu", "AXIS V1..V256", True),
    Verb("setpd", "AXIS V1..V256", True),
    Verb("getpu", "AXIS", True),
    Verb("getpd", "AXIS", True),
    # firmware_sim extensions: tests and diagnostics only
    Verb("gettick", "", False, axis=False),
    Verb("setfb", "AXIS linear|half-cosine|current-limited [SECONDS]", False),
    Verb("getfb", "AXIS", False),
    Verb("getcnt", "AXIS", False),
    Verb("getst", "AXIS", False),
    Verb("clrf", "AXIS", False),
    Verb("injf", "AXIS " + "|".join(FAULT_BITS), False),
    Verb("simstep", "AXIS", False),
)

BY_NAME: dict[str, Verb] = {v.name: v for v in VERBS}
REAL_VERBS: frozenset[str] = frozenset(v.name for v in VERBS if v.real)
"""The verbs a real ANC300 answers."""
MOVE_PATH: frozenset[str] = frozenset(
    {
        "echo",
        "ver",
        "getser",
        "setm",
        "getm",
        "setf",
        "getf",
        "setv",
        "getv",
        "seta",
        "stepu",
        "stepd",
        "stop",
        "stepw",
        "setpu",
        "setpd",
    }
)
"""The verbs the host's move path sends (apply, step, wait, stop, ground, hold an offset for the
camera calibration, read state)."""
assert MOVE_PATH <= REAL_VERBS


def verbs_of(dialect: str) -> frozenset[str]:
    """The verbs a console of ``dialect`` (one of :data:`DIALECTS`) answers."""
    if dialect not in DIALECTS:
        raise ValueError(f"unknown dialect {dialect!r}; known: {', '.join(DIALECTS)}")
    return REAL_VERBS if dialect == "anc300" else frozenset(BY_NAME)


def fault_names(word: int) -> tuple[str, ...]:
    """Names of the bits set in a fault word, lowest bit first."""
    return tuple(name for name, bit in sorted(FAULT_BITS.items(), key=lambda kv: kv[1]) if word & bit)
