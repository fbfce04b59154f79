"""The CAN segment inside firmware_sim: a frame reaches the other endpoints as it is sent.

A CAN controller hands a received frame to the firmware in its receive
interrupt, the moment the frame is on the wire.  This segment does the same for
the endpoints sharing one process (the CANopen nodes and the emulated SLCAN
adapter): :meth:`WireBus.send` calls every other endpoint's ``receiver`` in the
sender's thread before it returns.  No queue and no thread hand-over lie
between a host's SDO request and the node's answer, so the request is serviced
when it arrives, not when some receive thread next gets to run.

Rules for receivers, as for interrupt handlers: return quickly, never block on
I/O, and never hold a lock while sending that another sender may hold while it
delivers to you.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import can

Receiver = Callable[[can.Message], None]


class CanWire:
    """One CAN segment; :meth:`bus` adds an endpoint."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._endpoints: tuple[WireBus, ...] = ()

    def bus(self, receiver: Receiver | None = None) -> WireBus:
        """A new endpoint; ``receiver`` (settable later) gets every frame the others send."""
        endpoint = WireBus(self, receiver)
        with self._lock:
            self._endpoints = (*self._endpoints, endpoint)
        return endpoint

    def _deliver(self, sender: WireBus, message: can.Message) -> None:
        for endpoint in self._endpoints:  # a snapshot: endpoints may come and go meanwhile
            receiver = endpoint.receiver
            if endpoint is not sender and receiver is not None:
                receiver(message)

    def _detach(self, endpoint: WireBus) -> None:
        with self._lock:
            self._endpoints = tuple(e for e in self._endpoints if e is not endpoint)


class WireBus(can.BusABC):
    """An endpoint of a :class:`CanWire`, as a python-can bus for sending
    (``send``, ``send_periodic``); received frames go to :attr:`receiver`, never to ``recv``."""

    def __init__(self, wire: CanWire, receiver: Receiver | None = None) -> None:
        self._wire = wire
        self.receiver = receiver
        self.channel_info = "firmware_sim CAN wire"
        super().__init__(channel="wire")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._is_shutdown:
            raise can.CanOperationError("endpoint is shut down")
        msg.timestamp = time.time()
        self._wire._deliver(self, msg)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        raise can.CanOperationError("a wire endpoint delivers frames to its receiver, not to recv()")

    def shutdown(self) -> None:
        self.receiver = None
        self._wire._detach(self)
        super().shutdown()
