"""What a CANopen drive's codes mean to the host: the fault word's bits, EMCY error codes and
SDO abort codes, as docs/canopen.md lists them (firmware_sim's node sends the same)."""

from __future__ import annotations

from feeder.protocol import anc300

HOST_WATCHDOG = anc300.FAULT_BITS["host_watchdog"]
"""The fault word of an axis whose only fault is a host that fell silent."""


def fault_names(word: int) -> tuple[str, ...]:
    """Names of the bits set in a fault word: the protocol's, then ``fault<bit>`` for
    bits it does not name (a real drive may set more)."""
    unknown = word & ~sum(anc300.FAULT_BITS.values())
    return anc300.fault_names(word) + tuple(f"fault{bit}" for bit in range(32) if unknown >> bit & 1)


EMCY_MEANINGS = {
    0x0000: "error reset",
    0x1000: "generic error",
    0x4200: "over-temperature",
    0x6010: "tick watchdog",
    0x8130: "host watchdog",
    0x8210: "PDO length error",
}
"""What the amplifier's EMCY codes mean (firmware_sim's ``EMCY_CODES``, docs/canopen.md); other
codes are named by CiA 301's class (``canopen``'s :meth:`EmcyError.get_desc`)."""
ABORT_MESSAGES = {
    0x05040001: "command not valid (no such transfer)",
    0x06010001: "object is write-only",
    0x06010002: "object is read-only",
    0x06020000: "object does not exist",
    0x06090011: "sub-index does not exist",
    0x06040043: "conflicts with another setting",
    0x06090030: "value range exceeded",
    0x06090031: "value too high",
    0x06090032: "value too low",
    0x08000022: "refused in the present device state",
}
"""What the SDO abort codes the driver meets mean (CiA 301), in its errors."""
