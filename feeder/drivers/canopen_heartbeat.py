"""The host's CANopen heartbeat producer: a thread that beats as node ``host_id`` (NMT
OPERATIONAL, every ``period_s`` seconds) while the caller's control loop is alive.
Reference: docs/canopen.md.
"""

from __future__ import annotations

import logging
import threading
import time

import can
import canopen

log = logging.getLogger(__name__)

HOST_SILENCE_PERIODS = 3
"""The node's heartbeat consumer time, in the driver's heartbeat periods.  Once the caller has
called :meth:`~feeder.drivers.canopen_link.CanopenNodeLink.alive`, the host beats only while its
last call is younger than ``HOST_SILENCE_PERIODS - 1`` periods, so a stalled control loop lets the
consumer time expire."""


class HostHeartbeat:
    """The host's heartbeat (NMT state OPERATIONAL as node ``host_id``, every ``period_s``),
    sent from a thread of its own with :meth:`canopen.Network.send_message`.

    Not python-can's ``send_periodic``: on SocketCAN that is the kernel's broadcast manager,
    which goes on beating for a process that is stopped or deadlocked.  Once :meth:`alive` has
    been called, a beat goes out only while the last call is younger than
    ``HOST_SILENCE_PERIODS - 1`` periods; before the first call it beats unconditionally
    (tools that run no control loop).
    """

    def __init__(self, network: canopen.Network, host_id: int, period_s: float) -> None:
        self.network = network
        self.cob_id = 0x700 + host_id
        self.period_s = period_s
        self.fresh_s = (HOST_SILENCE_PERIODS - 1) * period_s
        """How long (s) one :meth:`alive` keeps the heartbeat going."""
        self._alive_at: float | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._run, daemon=True, name=f"canopen-host-heartbeat-{host_id}"
        )
        self._thread.start()

    def alive(self) -> None:
        """The caller's loop made progress now (cheap, any thread: one timestamp)."""
        self._alive_at = time.monotonic()

    def beating(self, now: float) -> bool:
        """Whether a beat due at ``now`` (``time.monotonic()``) goes out."""
        alive_at = self._alive_at
        return alive_at is None or now - alive_at < self.fresh_s

    def _run(self) -> None:
        due = time.monotonic()
        while True:
            now = time.monotonic()
            if self.beating(now):
                try:
                    self.network.send_message(self.cob_id, b"\x05")  # 5: OPERATIONAL
                except (can.CanError, OSError) as exc:  # the link's watchdog reports a dead bus
                    log.debug("host heartbeat 0x%03X not sent: %s", self.cob_id, exc)
            due = max(due + self.period_s, now)  # fixed rate; no burst after a late wake-up
            if self._stop.wait(max(due - time.monotonic(), 0.0)):
                return

    def stop(self) -> None:
        """Stop beating (at once; the thread ends within a moment)."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
