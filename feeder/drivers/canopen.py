"""The amplifier over CAN: a CANopen (CiA 301) master for one amplifier axis node.

Built on the ``canopen`` package's :class:`canopen.RemoteNode` and the node's EDS
(package data of :mod:`feeder.protocol.eds`; object reference in docs/canopen.md),
every object addressed by its EDS name:

- configuration by SDO (frequency, amplitude, flyback, mode),
- steps by RPDO1 (signed count + command sequence), each confirmed by the
  node's echo of the sequence in TPDO1 (a refusal sets a status bit),
- progress from TPDO1 (step counter, status word, error register),
- node loss from the heartbeat: no heartbeat for :data:`HEARTBEAT_LOSS_PERIODS`
  periods, or a heartbeat reporting anything but OPERATIONAL, marks the link
  lost; every later call raises :class:`AmplifierLinkLost` without sending.

The bus is plain python-can keyword arguments, so the transport is configuration::

    {"interface": "slcan", "channel": "/dev/pts/7", "bitrate": 500000, "sleep_after_open": 0}
    {"interface": "socketcan", "channel": "can0"}
    {"interface": "virtual", "channel": "test"}

Steps played: the node counts them (``Step counter``, in every TPDO1), so
``AmplifierStatus.step_counter`` is the drive's own count, not an estimate; the
end of a burst is the drive's ``moving`` bit going low in TPDO1 (:meth:`wait`).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import can
import canopen
from canopen.objectdictionary import ObjectDictionary
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from feeder.drivers.amplifier import (
    FLYBACK_SHAPES,
    Amplifier,
    AmplifierError,
    AmplifierLinkLost,
    AmplifierStatus,
    DriveSettings,
)
from feeder.protocol import anc300
from feeder.protocol.eds import MODES, bit_mask, object_dictionary

HOST_SILENCE_PERIODS = 3
"""The node's heartbeat consumer time, in the driver's heartbeat periods."""

HEARTBEAT_LOSS_PERIODS = 2.5
"""Missing heartbeats for this many periods = node lost (so it is reported
within 3 periods of the node's last breath)."""

CONSUMER_HEARTBEAT = "Consumer heartbeat time.Consumer heartbeat time 1"
TPDO1_TYPE = "TPDO1 communication parameter.Transmission type"
SETTINGS = ("Flyback shape", "Frequency", "Flyback time", "Amplitude")
"""The objects :meth:`CanopenAmplifier.apply` writes, in the order of ``_write_settings``' arguments."""

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


def fault_names(word: int) -> tuple[str, ...]:
    """Names of the bits set in a fault word: the protocol's, then ``fault<bit>`` for
    bits it does not name (a real drive may set more)."""
    unknown = word & ~sum(anc300.FAULT_BITS.values())
    return anc300.fault_names(word) + tuple(f"fault{bit}" for bit in range(32) if unknown >> bit & 1)


class CanopenAmplifier(Amplifier):
    """One amplifier axis reached as CANopen node ``node_id`` on a python-can bus.

    bus: python-can keyword arguments (``can.Bus(**bus)``).
    eds: the node's object dictionary; default: the packaged EDS
        (:func:`feeder.protocol.eds.object_dictionary`).
    heartbeat_s: heartbeat period of the node (the driver sets object 0x1017).
    timeout_s: SDO response and RPDO acknowledge timeout.
    supervise_host: the driver beats too (as node ``host_id``, every
        ``heartbeat_s``) and the node consumes it (0x1016): a host that dies
        mid-move gets the axis grounded (``host_watchdog``) after
        :data:`HOST_SILENCE_PERIODS` periods.  Off by default, like the
        firmware's ``--host-watchdog-s``.
    network: a connected :class:`canopen.Network` to share with other axes'
        drivers (one bus, several nodes; ``bus`` is then ignored); the caller
        disconnects it.  Default: the driver connects its own.
    """

    def __init__(
        self,
        bus: Mapping[str, Any],
        node_id: int,
        eds: ObjectDictionary | None = None,
        heartbeat_s: float = 0.25,
        timeout_s: float = 0.5,
        supervise_host: bool = False,
        host_id: int = 127,
        network: canopen.Network | None = None,
    ) -> None:
        self.node_id = node_id
        self.supervise_host = supervise_host
        self.host_id = host_id
        self._host_heartbeat: canopen.network.PeriodicMessageTask | None = None
        self.heartbeat_s = heartbeat_s
        self.timeout_s = timeout_s
        self._lock = threading.RLock()
        self._changed = threading.Condition()
        self._lost: str | None = None
        self._last_heartbeat = time.monotonic()
        self._started = False
        self._tpdo_seen = False
        self._counter = 0
        self._status_word = 0
        self._ack = 0
        self._sequence = 0
        self._closing = threading.Event()
        self._owns_network = network is None
        if network is None:
            network = canopen.Network()
            network.NOTIFIER_CYCLE = 0.1  # close() waits at most this long for the receiver
            network.connect(**dict(bus))
        self.network = network
        assert self.network.notifier is not None
        self.network.notifier.add_listener(_BusErrors(self._on_bus_error))
        with contextlib.ExitStack() as undo:  # any failure from here disconnects (our own network)
            if self._owns_network:
                undo.callback(self.network.disconnect)
            od = eds if eds is not None else object_dictionary(node_id)
            self.node = canopen.RemoteNode(node_id, od)
            self._moving = bit_mask(od, "Status word", "moving")
            self._refused = bit_mask(od, "Status word", "refused")
            self.node.sdo.RESPONSE_TIMEOUT = timeout_s
            self.network.add_node(self.node)
            self.node.nmt.add_heartbeat_callback(self._on_heartbeat)
            self._start()
            undo.pop_all()
        self._watchdog = threading.Thread(
            target=self._watch_heartbeat, daemon=True, name=f"canopen-heartbeat-{node_id}"
        )
        self._watchdog.start()

    # -- link setup and supervision --------------------------------------------

    def _start(self) -> None:
        """Wait for the node, set its heartbeat, take the PDOs from the EDS, start it."""
        try:
            self.node.nmt.wait_for_heartbeat(timeout=max(1.0, 5 * self.heartbeat_s))
        except canopen.nmt.NmtError as exc:
            raise AmplifierLinkLost(f"CANopen node {self.node_id}: no heartbeat") from exc
        self._sdo_write("Producer heartbeat time", round(self.heartbeat_s * 1000))
        if self.supervise_host:  # consumer first: it sees the first beat
            self._sdo_write(
                CONSUMER_HEARTBEAT, self.host_id << 16 | round(HOST_SILENCE_PERIODS * self.heartbeat_s * 1000)
            )
            self._host_heartbeat = self.network.send_periodic(
                0x700 + self.host_id, b"\x05", self.heartbeat_s
            )  # 5: OPERATIONAL
        self._sdo_write(TPDO1_TYPE, 255)  # TPDO1 event-driven: on change and on its timer
        self.node.tpdo.read(from_od=True)
        self.node.rpdo.read(from_od=True)
        self._tpdo = self.node.tpdo[1]
        self._rpdo = self.node.rpdo[1]
        self._tpdo.add_callback(self._on_tpdo)
        self._sequence = self._sdo_read("Command acknowledge")
        self.node.nmt.state = "OPERATIONAL"
        with self._changed:
            if not self._changed.wait_for(lambda: self._tpdo_seen, self.timeout_s + 0.2):
                raise AmplifierLinkLost(f"CANopen node {self.node_id}: no TPDO after start")
            # TPDOs flow only in OPERATIONAL: from here on any other state is a loss.
            self._started = True

    def _on_heartbeat(self, state: int) -> None:
        with self._changed:
            self._last_heartbeat = time.monotonic()
            if self._started and state != 5 and self._lost is None:
                name = canopen.nmt.NMT_STATES.get(state, str(state))
                self._lost = f"CANopen node {self.node_id} reported NMT state {name}"
                self._changed.notify_all()

    def _watch_heartbeat(self) -> None:
        limit = HEARTBEAT_LOSS_PERIODS * self.heartbeat_s
        while not self._closing.is_set():
            with self._changed:
                silent = time.monotonic() - self._last_heartbeat
                if silent >= limit and self._lost is None:
                    self._lost = f"CANopen node {self.node_id}: no heartbeat for {silent * 1000:.0f} ms"
                    self._changed.notify_all()
                if self._lost is not None:
                    return
            self._closing.wait(max(limit - silent, 0.005))

    def _on_tpdo(self, pdo: Any) -> None:
        with self._changed:
            self._counter = int(pdo["Step counter"].raw)
            self._status_word = int(pdo["Status word"].raw)
            self._ack = int(pdo["Command acknowledge"].raw)
            self._tpdo_seen = True
            self._changed.notify_all()

    def _on_bus_error(self, exc: Exception) -> None:
        """The bus itself failed (e.g. the adapter's port vanished): the link is lost."""
        with self._changed:
            if self._lost is None:
                self._lost = f"CANopen node {self.node_id}: CAN bus error: {exc}"
                self._changed.notify_all()
        time.sleep(0.05)  # the receiver retries; do not spin on a dead port

    def _check_link(self) -> None:
        if self._lost is not None:
            raise AmplifierLinkLost(self._lost)

    @property
    def lost(self) -> str | None:
        """Why the link was declared lost, or None while it is healthy."""
        return self._lost

    # -- SDO and RPDO -----------------------------------------------------------

    def _sdo_write(self, name: str, value: int) -> None:
        """Write object ``name`` (its EDS name; ``Record.Sub`` for a sub-object)."""
        self._check_link()
        try:
            self.node.sdo[name].raw = value
        except SdoAbortedError as exc:
            raise AmplifierError(self._abort_text(exc, name, value)) from exc
        except (SdoCommunicationError, can.CanError, OSError) as exc:  # no answer, or no bus
            raise AmplifierLinkLost(f"CANopen node {self.node_id}: {exc}") from exc

    def _sdo_read(self, name: str) -> int:
        """Read object ``name`` (its EDS name)."""
        self._check_link()
        try:
            return int(self.node.sdo[name].raw)
        except SdoAbortedError as exc:
            raise AmplifierError(self._abort_text(exc, name, None)) from exc
        except (SdoCommunicationError, can.CanError, OSError) as exc:  # no answer, or no bus
            raise AmplifierLinkLost(f"CANopen node {self.node_id}: {exc}") from exc

    def _abort_text(self, exc: SdoAbortedError, name: str, value: int | None) -> str:
        what = f"{name} = {value}" if value is not None else name
        reason = ABORT_MESSAGES.get(exc.code, "refused")
        return f"CANopen node {self.node_id}: {what}: {reason} (SDO abort 0x{exc.code:08X})"

    def _command(self, count: int) -> None:
        """Send ``count`` by RPDO1 and wait for the node's acknowledge in TPDO1."""
        with self._lock:
            self._check_link()
            self._sequence = (self._sequence + 1) % 256
            sequence = self._sequence
            self._rpdo["Step command"].raw = count
            self._rpdo["Command sequence"].raw = sequence
            try:
                self._rpdo.transmit()
            except (can.CanError, OSError) as exc:  # the adapter's port is gone
                raise AmplifierLinkLost(f"CANopen node {self.node_id}: {exc}") from exc
            with self._changed:
                acked = self._changed.wait_for(
                    lambda: self._ack == sequence or self._lost is not None, self.timeout_s
                )
                self._check_link()
                refused = self._status_word & self._refused
            if not acked:
                raise AmplifierLinkLost(f"CANopen node {self.node_id}: step command not acknowledged")
        if refused:
            state = self.status()
            reason = f"fault {', '.join(state.faults)}" if state.fault_word else f"mode {state.mode}"
            raise AmplifierError(f"CANopen node {self.node_id}: step {count} refused ({reason})")

    # -- the Amplifier interface -----------------------------------------------

    def apply(self, settings: DriveSettings) -> None:
        """Write the settings; if the node refuses one, restore the previous ones."""
        if settings.flyback_shape not in FLYBACK_SHAPES:
            raise AmplifierError(f"unknown flyback shape {settings.flyback_shape!r}")
        wanted = (
            FLYBACK_SHAPES.index(settings.flyback_shape),
            round(settings.frequency_hz * 1000),
            round((settings.flyback_s or 0.0) * 1e9),
            round(settings.amplitude_v * 1000),
        )
        with self._lock:
            previous = tuple(self._sdo_read(name) for name in SETTINGS)
            try:
                self._write_settings(*wanted)
            except AmplifierError:
                self._write_settings(*previous)
                raise

    def _write_settings(self, shape: int, frequency_mhz: int, flyback_ns: int, amplitude_mv: int) -> None:
        """SDO writes in an order the firmware accepts from any previous settings:
        current-limited flyback first (no timing constraint), then frequency, flyback
        time and the wanted shape (checked against the new period), then amplitude."""
        current_limited = FLYBACK_SHAPES.index("current-limited")
        writes = [
            ("Flyback shape", current_limited),
            ("Frequency", frequency_mhz),
            ("Flyback time", flyback_ns),
        ]
        if shape != current_limited and shape < len(FLYBACK_SHAPES):
            writes.append(("Flyback shape", shape))
        for name, value in [*writes, ("Amplitude", amplitude_mv)]:
            self._sdo_write(name, value)

    def step(self, count: int) -> None:
        if count == 0:
            raise AmplifierError("step count must not be 0")
        self._command(int(count))

    def run_continuous(self, forward: bool) -> None:
        with self._lock:
            self._sdo_write("Continuous", 1 if forward else -1)

    def stop(self) -> None:
        self._command(0)

    def wait(self, timeout_s: float) -> bool:
        with self._changed:
            done = self._changed.wait_for(
                lambda: not self._status_word & self._moving or self._lost is not None, timeout_s
            )
            self._check_link()
            return done

    def ground(self) -> None:
        with self._lock:
            self._sdo_write("Mode", MODES.index("gnd"))

    def enable(self) -> None:
        with self._lock:
            self._sdo_write("Mode", MODES.index("stp"))

    def clear_faults(self) -> None:
        """Clear the node's latched fault word (``Fault reset``); the output stays grounded."""
        with self._lock:
            self._sdo_write("Fault reset", 1)

    def status(self) -> AmplifierStatus:
        with self._lock:
            mode = self._sdo_read("Mode")
            frequency_mhz = self._sdo_read("Frequency")
            amplitude_mv = self._sdo_read("Amplitude")
            fault_word = self._sdo_read("Fault word")
            counter = self._sdo_read("Step counter")
            moving = bool(self._sdo_read("Status word") & self._moving)
        return AmplifierStatus(
            mode=MODES[mode] if mode < len(MODES) else str(mode),
            frequency_hz=frequency_mhz / 1000,
            amplitude_v=amplitude_mv / 1000,
            step_counter=counter,
            moving=moving,
            fault_word=fault_word,
            faults=fault_names(fault_word),
        )

    @property
    def step_counter(self) -> int:
        """The step counter from the latest TPDO1 (no bus traffic)."""
        with self._changed:
            return self._counter

    def close(self) -> None:
        """Release the link; the output is left alone (the node stops watching us first)."""
        if self._closing.is_set():
            return
        if self._host_heartbeat is not None:
            if self._lost is None:
                with contextlib.suppress(AmplifierError):
                    self._sdo_write(CONSUMER_HEARTBEAT, 0)
            self._host_heartbeat.stop()
        self._closing.set()
        if self._watchdog.is_alive():
            self._watchdog.join(timeout=1.0)
        if not self._owns_network:
            return
        # the adapter may be gone already (e.g. its pty closed): nothing left to release
        with contextlib.suppress(can.CanError, OSError):
            self.network.disconnect()


class _BusErrors(can.Listener):
    """Passes exceptions from the bus receiver to a callback instead of killing it."""

    def __init__(self, callback: Callable[[Exception], None]) -> None:
        self._callback = callback

    def on_message_received(self, msg: can.Message) -> None:
        """Frames are the network's business."""

    def on_error(self, exc: Exception) -> None:
        self._callback(exc)
