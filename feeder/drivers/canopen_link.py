"""The amplifier's CANopen node as the host sees it: start-up, SDO, heartbeat, loss.

:class:`CanopenNodeLink` is one node on a python-can bus (``canopen``'s
:class:`canopen.RemoteNode` with the node's EDS), shared by the drivers of its axes
(:class:`feeder.drivers.canopen.CanopenAmplifier`): it starts the node, checks it
is the product its EDS describes and maps its PDOs as the EDS does, serialises SDO
transfers, receives every axis' TPDO and EMCY and watches the node's heartbeat once for
all axes.  With ``supervise_host`` it also beats as the host (:class:`HostHeartbeat`), from a
thread of its own and only while the caller's control loop says it is alive.
Reference: docs/canopen.md.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import can
import canopen
from canopen.objectdictionary import ObjectDictionary
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from feeder import stall
from feeder.drivers.amplifier import AmplifierError, AmplifierLinkLost
from feeder.drivers.canopen_codes import ABORT_MESSAGES, EMCY_MEANINGS, HOST_WATCHDOG, fault_names
from feeder.drivers.canopen_heartbeat import HOST_SILENCE_PERIODS, HostHeartbeat
from feeder.errors import InputError
from feeder.protocol.can_frames import canopen_frames_only
from feeder.protocol.eds import axis_count, axis_object, object_dictionary

log = logging.getLogger(__name__)

DEFAULT_HOST_ID = 127
"""The node id the host beats as (``[amplifier.can] host_id``)."""

HEARTBEAT_LOSS_PERIODS = 2.5
"""Missing heartbeats for this many periods = node lost (so it is reported
within 3 periods of the node's last breath)."""

CONSUMER_HEARTBEAT = "Consumer heartbeat time.Consumer heartbeat time 1"
PRODUCT_CODE = "Identity object.Product code"
TPDO_OBJECTS = ("Step counter", "Status word", "Command acknowledge")
"""What the driver takes from each axis' TPDO (one-axis EDS names)."""
TPDO_EVENT_TIMER_MS = 100
"""The event timer the driver gives every TPDO (ms): the node sends it at least this often,
so its first TPDO after the start comes within the wait for it (``timeout_s`` + 0.2 s), even
from a drive that sends none on entering OPERATIONAL."""


def tpdo_parameter(axis: int, name: str) -> str:
    """Sub-object ``name`` of axis ``axis``' TPDO communication parameter (axis n sends TPDOn)."""
    return f"TPDO{axis} communication parameter.{name}"


@dataclass
class _Feedback:
    """One axis' latest TPDO, and the sequence of its last RPDO command."""

    counter: int = 0
    status_word: int = 0
    ack: int = 0
    seen: bool = False
    sequence: int = 0
    emcy: str | None = None
    """The latest EMCY naming this axis (cleared by an error reset, code 0x0000)."""
    emcy_pending: bool = False
    """``emcy`` arrived and no call has raised it yet."""


class CanopenNodeLink:
    """CANopen node ``node_id`` on a python-can bus, shared by the drivers of its axes.

    Starts the node (SDO probe, PDO mapping check, heartbeat, NMT OPERATIONAL), serialises SDO
    transfers (one SDO channel per node), receives every axis' TPDO and watches the
    node's heartbeat: once the node is lost, every axis is.

    bus: python-can keyword arguments (``can.Bus(**bus)``).
    eds: the node's object dictionary; default: the packaged one-axis EDS
        (:func:`feeder.protocol.eds.object_dictionary`).  It says how many axes
        (:attr:`axes`) the node has.
    heartbeat_s: heartbeat period of the node (the driver sets object 0x1017).
    timeout_s: SDO response and RPDO acknowledge timeout.
    supervise_host: the driver beats too (as node ``host_id``, every
        ``heartbeat_s``, :class:`HostHeartbeat`) and the node consumes it (0x1016): a
        host that dies, or whose control loop stops calling :meth:`alive`, mid-move gets
        the node's moving axes grounded (``host_watchdog``) after
        :data:`HOST_SILENCE_PERIODS` periods.  Off by default, like the
        firmware's ``--host-watchdog-s``.
    host_id: the node id the host beats as, 1..127, not ``node_id`` (the daemon's
        ``[amplifier.can] host_id``).
    network: a connected :class:`canopen.Network` to share with other nodes'
        drivers (one bus, several nodes; ``bus`` is then ignored); the caller
        disconnects it.  Default: the link connects its own.  Either way the link makes
        it ignore 29-bit frames (:func:`~feeder.protocol.can_frames.canopen_frames_only`); ``bus``'s own
        ``can_filters`` go to python-can as given.

    EMCY: each is logged (WARNING) and remembered for the axis its byte 7 names (every
    axis of the node when it names none of them); the axis' next step or continuous run, or a wait in
    progress, raises it (:meth:`raise_emcy`); an error reset (code 0x0000) clears it.

    The link closes when the last axis driver on it is closed (:meth:`release`).
    """

    def __init__(
        self,
        bus: Mapping[str, Any],
        node_id: int,
        eds: ObjectDictionary | None = None,
        heartbeat_s: float = 0.25,
        timeout_s: float = 0.5,
        supervise_host: bool = False,
        host_id: int = DEFAULT_HOST_ID,
        network: canopen.Network | None = None,
    ) -> None:
        if isinstance(host_id, bool) or not isinstance(host_id, int) or not 1 <= host_id <= 127:
            raise InputError("host_id", f"the host's node id must be an integer in 1..127, got {host_id!r}")
        if supervise_host and host_id == node_id:
            raise InputError("host_id", f"the host's node id {host_id} is the amplifier node's")
        self.node_id = node_id
        self.supervise_host = supervise_host
        self.host_id = host_id
        self.host_heartbeat: HostHeartbeat | None = None
        self.heartbeat_s = heartbeat_s
        self.timeout_s = timeout_s
        self.sdo_lock = threading.Lock()
        self.changed = threading.Condition()
        self._lost: str | None = None
        self._last_heartbeat = time.monotonic()
        self._started = False
        self._users = 0
        self._closing = threading.Event()
        self._owns_network = network is None
        od = eds if eds is not None else object_dictionary(node_id)
        self.axes = axis_count(od)
        self.feedback = {axis: _Feedback() for axis in range(1, self.axes + 1)}
        self._tpdo_names = {
            axis: tuple(axis_object(od, axis, name) for name in TPDO_OBJECTS) for axis in self.feedback
        }
        if network is None:
            network = canopen.Network()
            network.NOTIFIER_CYCLE = 0.1  # close() waits at most this long for the receiver
            network.connect(**dict(bus))
        self.network = network
        assert self.network.notifier is not None
        canopen_frames_only(self.network)
        self.network.notifier.add_listener(_BusErrors(self._on_bus_error))
        with contextlib.ExitStack() as undo:  # any failure from here disconnects (our own network)
            if self._owns_network:
                undo.callback(disconnect, self.network)
            self.node = canopen.RemoteNode(node_id, od)
            self.node.sdo.RESPONSE_TIMEOUT = timeout_s
            self.network.add_node(self.node)
            self.node.nmt.add_heartbeat_callback(self._on_heartbeat)
            self.node.emcy.add_callback(self._on_emcy)
            undo.callback(self._stop_beating)  # a failed start leaves no host heartbeat behind
            self._start()
            undo.pop_all()
        stall.watch()
        self._watchdog = threading.Thread(
            target=self._watch_heartbeat, daemon=True, name=f"canopen-heartbeat-{node_id}"
        )
        self._watchdog.start()

    # -- start-up and supervision -----------------------------------------------

    def _start(self) -> None:
        """Bring the node to PRE-OPERATIONAL, probe it by SDO (its product code, which must be
        the EDS's), check its PDO mappings against the EDS, enable its heartbeat (0x1017) and
        wait for a beat, clear a host_watchdog latched before this host (supervising),
        start it and wait for every axis' first TPDO.

        The heartbeat is enabled before it is awaited: a node may ship with 0x1017 = 0
        (CiA 301: no heartbeat), and a booted node's only unasked frame, its boot-up
        message, may have gone by before the driver listened.
        """
        product = self.node.object_dictionary.device_information.product_number
        # a node another master left STOPPED serves no SDO: bring it to PRE-OPERATIONAL (an NMT
        # command every state takes; it stops the PDOs, which the driver starts again below)
        self.node.nmt.state = "PRE-OPERATIONAL"
        found = self.sdo_read(PRODUCT_CODE)  # the first request: "not answering" if nobody is there
        if product is not None and found != product:
            raise AmplifierError(
                f"CANopen node {self.node_id} is product 0x{found:08X}, its EDS describes "
                f"0x{product:08X} ({self.axes} axis per node): wrong EDS or node id"
            )
        self.node.tpdo.read(from_od=True)
        self.node.rpdo.read(from_od=True)
        for axis in self.feedback:
            self._check_mapping(f"TPDO{axis}", self.node.tpdo[axis])
            self._check_mapping(f"RPDO{axis}", self.node.rpdo[axis])
        period_ms = round(self.heartbeat_s * 1000)
        self.sdo_write("Producer heartbeat time", period_ms)
        try:
            self.node.nmt.wait_for_heartbeat(timeout=max(1.0, 5 * self.heartbeat_s))
        except canopen.nmt.NmtError as exc:
            raise AmplifierLinkLost(
                f"CANopen node {self.node_id}: no heartbeat after setting its period to {period_ms} ms"
            ) from exc
        if self.supervise_host:  # consumer first: it sees the first beat
            self.sdo_write(
                CONSUMER_HEARTBEAT, self.host_id << 16 | round(HOST_SILENCE_PERIODS * self.heartbeat_s * 1000)
            )
            self.host_heartbeat = HostHeartbeat(self.network, self.host_id, self.heartbeat_s)
            self._clear_host_watchdog()
        for axis, feedback in self.feedback.items():
            self.sdo_write(tpdo_parameter(axis, "Transmission type"), 255)  # on change and on its timer
            self.sdo_write(tpdo_parameter(axis, "Event timer"), TPDO_EVENT_TIMER_MS)
            self.node.tpdo[axis].add_callback(functools.partial(self._on_tpdo, axis))
            feedback.sequence = self.sdo_read(self.name(axis, "Command acknowledge"))
        self.node.nmt.state = "OPERATIONAL"
        with self.changed:
            all_seen = self.changed.wait_for(
                lambda: all(f.seen for f in self.feedback.values()), self.timeout_s + 0.2
            )
            # TPDOs flow only in OPERATIONAL: from here on any other state is a loss.
            self._started = all_seen
        if not all_seen:  # asked outside the lock: the receive thread's callbacks take it
            raise AmplifierLinkLost(f"CANopen node {self.node_id}: no TPDO after start{self._latched()}")

    def _stop_beating(self) -> None:
        if self.host_heartbeat is not None:
            self.host_heartbeat.stop()

    def _latched(self) -> str:
        """Why a node may not stay OPERATIONAL: its latched faults, as a clause ("" if none)."""
        named = []
        with contextlib.suppress(AmplifierError):
            for axis in self.feedback:
                word = self.sdo_read(self.name(axis, "Fault word"))
                if word:
                    named.append(f"axis {axis}: {', '.join(fault_names(word))}")
        if not named:
            return ""
        return f" (faults latched, {'; '.join(named)}: a node may leave OPERATIONAL while they are)"

    def _clear_host_watchdog(self) -> None:
        """Clear a ``host_watchdog`` that a host before this one latched (it fell silent
        mid-move): a host supervises the node again, and the axis stays grounded.  Needed, not
        only tidy: a node that leaves OPERATIONAL while its error register is set (CANopenNode's
        ``CO_NMT_ERR_ON_ERR_REG``, in its examples' defaults) would refuse the start below."""
        if not self.sdo_read("Error register"):
            return
        for axis in self.feedback:
            if self.sdo_read(self.name(axis, "Fault word")) == HOST_WATCHDOG:
                log.warning("%s axis %d: clearing the host_watchdog latched before this host", self.who, axis)
                self.sdo_write(self.name(axis, "Fault reset"), 1)

    def _check_mapping(self, label: str, pdo: canopen.pdo.PdoMap) -> None:
        """Refuse a node that maps ``pdo`` (named ``label``) otherwise than the EDS does: the
        driver packs and unpacks the PDO by the EDS's mapping, so a different one would put
        e.g. the step counter in the wrong bytes.  Reads the node's mapping by SDO."""
        record = pdo.map_array.od
        expected = [(variable.index, variable.subindex, variable.length) for variable in pdo.map]
        found = []
        for sub in range(1, self._sdo_upload(record.index, 0, 1, record.name) + 1):
            entry = self._sdo_upload(record.index, sub, 4, record.name)
            found.append((entry >> 16, entry >> 8 & 0xFF, entry & 0xFF))
        if found != expected:
            raise AmplifierError(
                f"{self.who}: {label} (0x{record.index:04X}) maps {self._describe(found)}, "
                f"its EDS {self._describe(expected)}: wrong EDS, or the drive's mapping was changed"
            )

    def _describe(self, mapping: list[tuple[int, int, int]]) -> str:
        """A PDO mapping as object names (index:sub-index for objects the EDS lacks), each
        with its bit length where that is not its type's."""
        names = []
        for index, subindex, bits in mapping:
            variable = self.node.object_dictionary.get_variable(index, subindex)
            if variable is None:
                names.append(f"0x{index:04X}:{subindex:02X} ({bits} bit)")
            else:
                names.append(variable.qualname + (f" ({bits} bit)" if bits != len(variable) else ""))
        return "[" + ", ".join(names) + "]"

    def name(self, axis: int, name: str) -> str:
        """The EDS name of axis ``axis``' object ``name`` on this node."""
        return axis_object(self.node.object_dictionary, axis, name)

    def _on_heartbeat(self, state: int) -> None:
        with self.changed:
            self._last_heartbeat = time.monotonic()
            if self._started and state != 5 and self._lost is None:
                name = canopen.nmt.NMT_STATES.get(state, str(state))
                self._lost = f"CANopen node {self.node_id} reported NMT state {name}"
                self.changed.notify_all()

    def _watch_heartbeat(self) -> None:
        limit = HEARTBEAT_LOSS_PERIODS * self.heartbeat_s
        while not self._closing.is_set():
            with self.changed:
                now = time.monotonic()
                silent = now - self._last_heartbeat
                if silent >= limit and stall.stalled_since(self._last_heartbeat) > 0:
                    log.warning("%s: the host stood still: the node's heartbeat is judged again", self.who)
                    self._last_heartbeat, silent = now, 0.0  # the silence was ours
                if silent >= limit and self._lost is None:
                    self._lost = f"CANopen node {self.node_id}: no heartbeat for {silent * 1000:.0f} ms"
                    self.changed.notify_all()
                if self._lost is not None:
                    return
            self._closing.wait(max(limit - silent, 0.005))

    def _on_tpdo(self, axis: int, pdo: Any) -> None:
        counter, status_word, ack = self._tpdo_names[axis]
        with self.changed:
            feedback = self.feedback[axis]
            feedback.counter = int(pdo[counter].raw)
            feedback.status_word = int(pdo[status_word].raw)
            feedback.ack = int(pdo[ack].raw)
            feedback.seen = True
            self.changed.notify_all()

    def _on_emcy(self, entry: canopen.emcy.EmcyError) -> None:
        """An EMCY from the node (receive thread): log it, remember it for the axis its byte 7
        names (every axis when it names none of them), wake waits; an error reset clears it.
        A reset naming no axis clears every axis only once the error register it carries is
        0: CANopenNode resets each error as it clears, with byte 7 its own (usually 0)."""
        data = bytes(entry.data)
        named = data[4] if len(data) >= 5 else 0  # byte 7 of the frame: the axis in its node
        axes = [named] if named in self.feedback else list(self.feedback)
        reset = entry.code & 0xFF00 == 0  # error reset / no error (CiA 301)
        if reset and named not in self.feedback and entry.register:
            log.info("%s: EMCY error reset on no axis, errors left (0x%02X)", self.who, entry.register)
            return
        if reset:
            log.info("%s: EMCY 0x%04X error reset on axis %s", self.who, entry.code, named or "all")
            with self.changed:
                for axis in axes:
                    self.feedback[axis].emcy = None
                    self.feedback[axis].emcy_pending = False
                self.changed.notify_all()
            return
        meaning = EMCY_MEANINGS.get(entry.code) or entry.get_desc().lower() or "error"
        where = f"axis {axes[0]}" if len(axes) == 1 else f"axes {', '.join(map(str, axes))}"
        message = f"{self.who}: EMCY 0x{entry.code:04X} {meaning} on {where}"
        log.warning("%s (error register 0x%02X)", message, entry.register)
        with self.changed:
            for axis in axes:
                self.feedback[axis].emcy = message
                self.feedback[axis].emcy_pending = True
            self.changed.notify_all()

    def raise_emcy(self, axis: int) -> None:
        """Raise :class:`AmplifierError` with axis ``axis``' EMCY that no call has raised yet
        (once: it is then taken); call with :attr:`changed` held or not."""
        with self.changed:
            feedback = self.feedback[axis]
            if feedback.emcy_pending:
                feedback.emcy_pending = False
                raise AmplifierError(str(feedback.emcy))

    def forget_emcy(self, axis: int) -> None:
        """Drop axis ``axis``' EMCY (its faults were cleared on the host's request)."""
        with self.changed:
            self.feedback[axis].emcy = None
            self.feedback[axis].emcy_pending = False

    def alive(self) -> None:
        """The caller's control loop is making progress: keeps the host heartbeat going
        (:class:`HostHeartbeat`; nothing without ``supervise_host``).  Cheap, any thread."""
        if self.host_heartbeat is not None:
            self.host_heartbeat.alive()

    def _on_bus_error(self, exc: Exception) -> None:
        """The bus itself failed (e.g. the adapter's port vanished): the node is lost."""
        with self.changed:
            if self._lost is None:
                self._lost = f"CANopen node {self.node_id}: CAN bus error: {exc}"
                self.changed.notify_all()
        time.sleep(0.05)  # the receiver retries; do not spin on a dead port

    def check(self) -> None:
        """Raise :class:`AmplifierLinkLost` once the node is lost."""
        if self._lost is not None:
            raise AmplifierLinkLost(self._lost)

    @property
    def lost(self) -> str | None:
        """Why the node was declared lost, or None while it is healthy."""
        return self._lost

    # -- SDO ---------------------------------------------------------------------

    def beating(self) -> bool:
        """The node's heartbeat is fresh, whatever state it reports: it is there to answer."""
        return time.monotonic() - self._last_heartbeat < HEARTBEAT_LOSS_PERIODS * self.heartbeat_s

    def sdo_write(self, name: str, value: int, who: str | None = None, *, lost_ok: bool = False) -> None:
        """Write object ``name`` (its EDS name; ``Record.Sub`` for a sub-object); ``who``
        names the axis in errors.  ``lost_ok``: tried even once the node is lost, while it
        still beats (grounding: a node that left OPERATIONAL serves SDO in PRE-OPERATIONAL,
        and CiA 301 does not make a state change stop its outputs)."""
        with self._transfer(f"{name} = {value}", who, lost_ok=lost_ok and self.beating()):
            self.node.sdo[name].raw = value

    def sdo_read(self, name: str, who: str | None = None) -> int:
        """Read object ``name`` (its EDS name)."""
        with self._transfer(name, who):
            value = int(self.node.sdo[name].raw)
        return value

    def _sdo_upload(self, index: int, subindex: int, size: int, what: str) -> int:
        """Read unsigned object ``index``:``subindex`` of ``size`` bytes by its numbers (for
        sub-indices the EDS may lack); ``what`` names it in errors."""
        with self._transfer(f"{what} sub-index {subindex}", None):
            data = self.node.sdo.upload(index, subindex)
        return int.from_bytes(data[:size], "little")

    @contextlib.contextmanager
    def _transfer(self, what: str, who: str | None, lost_ok: bool = False) -> Iterator[None]:
        """One SDO transfer (``what``: the object, and the value written), serialised; its
        failures as :class:`AmplifierError` (an abort) or :class:`AmplifierLinkLost`.  Refused
        at once on a lost node unless ``lost_ok``."""
        if not lost_ok:
            self.check()
        try:
            with self.sdo_lock:
                yield
        except SdoAbortedError as exc:
            reason = ABORT_MESSAGES.get(exc.code, "refused")
            raise AmplifierError(f"{who or self.who}: {what}: {reason} (SDO abort 0x{exc.code:08X})") from exc
        except SdoCommunicationError as exc:  # no (valid) answer within the timeout
            raise AmplifierLinkLost(f"{who or self.who}: not answering ({exc})") from exc
        except (can.CanError, OSError) as exc:  # no bus
            raise AmplifierLinkLost(f"{who or self.who}: {exc}") from exc

    @property
    def who(self) -> str:
        return f"CANopen node {self.node_id}"

    # -- users ---------------------------------------------------------------------

    def acquire(self) -> None:
        """One more axis driver uses the link."""
        self._users += 1

    def release(self) -> None:
        """An axis driver is done: the last one closes the link."""
        self._users -= 1
        if self._users <= 0:
            self.close()

    def close(self) -> None:
        """Release the node; outputs are left alone (the node stops watching us first)."""
        if self._closing.is_set():
            return
        if self.host_heartbeat is not None and self._lost is None:
            with contextlib.suppress(AmplifierError):
                self.sdo_write(CONSUMER_HEARTBEAT, 0)
        self._stop_beating()
        self._closing.set()
        if self._watchdog.is_alive():
            self._watchdog.join(timeout=1.0)
        if self._owns_network:
            disconnect(self.network)


def disconnect(network: canopen.Network) -> None:
    """Let ``network``'s bus go.  canopen raises, once the bus is shut down, the error that
    stopped its receiver (a bus gone: python-can's ``CanOperationError``, e.g. ENETDOWN, or a
    closed pty): the link was reported lost for it already, so it is logged, not raised."""
    try:
        network.disconnect()
    except (can.CanError, OSError) as exc:
        log.info("CAN bus released after its error: %s", exc)


class _BusErrors(can.Listener):
    """Passes exceptions from the bus receiver to a callback instead of killing it."""

    def __init__(self, callback: Callable[[Exception], None]) -> None:
        self._callback = callback

    def on_message_received(self, msg: can.Message) -> None:
        """Frames are the network's business."""

    def on_error(self, exc: Exception) -> None:
        self._callback(exc)
