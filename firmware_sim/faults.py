"""What the amplifier's firmware refuses and the faults it latches.

Refused values raise :class:`LimitError`, other refusals :class:`FirmwareError`;
their ``str()`` is the console's error line.

Safety state machine per axis: a latched ``fault_word`` (see :class:`Fault`);
any fault grounds the axis and stops it.  A stepping ``setm`` re-arms an axis whose
only faults are the watchdogs (:data:`REARMABLE_FAULTS`: the stall is over once the host
commands again); with any other fault stepping modes are refused until
:meth:`firmware_sim.axis.Axis.clear_faults`.  Faults: ``WATCHDOG`` (the tick loop
stalled longer than ``watchdog_s``), ``HOST_WATCHDOG`` (no host command for
``host_watchdog_s`` while an axis moves; off by default), ``OVERTEMP``
(injected by the host, for tests).  An underrun is counted, not a fault: the
held sample is a constant, safe output.
"""

from __future__ import annotations

import enum
import math

from feeder.protocol.anc300 import FAULT_BITS


class FirmwareError(Exception):
    """A command the firmware refuses; ``str()`` is the console's error line."""


class LimitError(FirmwareError):
    """A value outside its allowed range ``[lo, hi]``."""

    def __init__(self, field: str, value: float, lo: float, hi: float) -> None:
        super().__init__(f"Value out of range: {field} = {_plain(value)} not in [{_plain(lo)}, {_plain(hi)}]")
        self.field = field
        self.value = value
        self.lo = lo
        self.hi = hi


def _plain(value: float) -> str:
    """A number in plain fixed point (no exponent), trailing zeros dropped."""
    if not (math.isfinite(value) and abs(value) < 1e15):
        return "(too large)"
    return f"{value:.9f}".rstrip("0").rstrip(".")


class Fault(enum.IntFlag):
    """Bits of an axis' latched fault word (0 = healthy)."""

    WATCHDOG = 0x01
    HOST_WATCHDOG = 0x02
    OVERTEMP = 0x04


assert {f.name.lower(): int(f) for f in Fault if f.name} == FAULT_BITS, "Fault drifted from the protocol"
REARMABLE_FAULTS = int(Fault.WATCHDOG | Fault.HOST_WATCHDOG)
"""Faults a stepping ``setm`` clears (the stall is over once the host commands again)."""
