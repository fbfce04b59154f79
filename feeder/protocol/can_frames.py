"""Which CAN frames are CANopen's: CiA 301 uses 11-bit data frames only (no 29-bit identifiers,
no remote frames: no RTR-requested PDOs, no node guarding).  ``canopen``'s own listener drops
remote and error frames but not 29-bit ones, whose low bits may be a PDO's, an EMCY's or a
heartbeat's identifier: both the host's driver and firmware_sim's node listen through
:class:`CanopenFrames` instead.
"""

from __future__ import annotations

import can
import canopen


def is_canopen_frame(msg: can.Message) -> bool:
    """Whether ``msg`` is a CANopen frame (an 11-bit data frame)."""
    return not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame)


class CanopenFrames(canopen.network.MessageListener):
    """``canopen``'s listener, passing on only :func:`is_canopen_frame`'s frames."""

    def on_message_received(self, msg: can.Message) -> None:
        if is_canopen_frame(msg):
            super().on_message_received(msg)


def canopen_frames_only(network: canopen.Network) -> None:
    """Make connected ``network`` listen through :class:`CanopenFrames` (once: a network shared
    by several links).

    In its listener, not by python-can's ``can_filters``: those stay the user's, and some
    interfaces apply a filter's ``extended`` key in hardware to one frame format only (kvaser:
    29-bit frames pass a filter set for 11-bit ones)."""
    assert network.notifier is not None
    for listeners in (network.listeners, network.notifier.listeners):
        for index, listener in enumerate(listeners):
            if type(listener) is canopen.network.MessageListener:
                listeners[index] = CanopenFrames(network)  # one assignment: the receiver sees either
