"""The amplifier over CAN: a CANopen (CiA 301) master for the amplifier's axis nodes.

Built on the ``canopen`` package's :class:`canopen.RemoteNode` and the node's EDS
(package data of :mod:`feeder.protocol.eds`; object reference in docs/canopen.md),
every object addressed by its EDS name.  A node has one axis or several (the EDS
says which, :func:`feeder.protocol.eds.axis_count`): :class:`CanopenNodeLink` is the
node (start-up, SDO, heartbeat), shared by one :class:`CanopenAmplifier` per axis:

- configuration by SDO (frequency, amplitude, flyback, mode), the axis' own objects,
- steps by the axis' RPDO (signed count + command sequence), each confirmed by the
  node's echo of the sequence in the axis' TPDO (a refusal sets a status bit),
- progress from the axis' TPDO (step counter, status word, error register),
- faults as they latch from the node's EMCY: the axis' next step or continuous run
  (or a wait in progress) raises :class:`AmplifierError` naming the code and its meaning,
- node loss from the node's heartbeat: no heartbeat for
  :data:`~feeder.drivers.canopen_link.HEARTBEAT_LOSS_PERIODS`
  periods, or a heartbeat reporting anything but OPERATIONAL, marks the node lost;
  every later call on any of its axes raises :class:`AmplifierLinkLost` without sending,
  but :meth:`~CanopenAmplifier.ground`, which is tried by SDO while the node still beats
  (CiA 301: a node that left OPERATIONAL may drive on, and serves SDO in PRE-OPERATIONAL).

The bus is plain python-can keyword arguments, so the transport is configuration::

    {"interface": "slcan", "channel": "/dev/pts/7", "bitrate": 500000, "sleep_after_open": 0}
    {"interface": "socketcan", "channel": "can0"}
    {"interface": "virtual", "channel": "test"}

Steps played: the node counts them (``Step counter``, in every TPDO), so
``AmplifierStatus.step_counter`` is the drive's own count, not an estimate; the
end of a burst is the drive's ``moving`` bit going low in the TPDO (:meth:`wait`).
:meth:`CanopenAmplifier.steps_played` takes the count from the TPDO when that count
is final, else reads that one object by SDO.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Mapping
from typing import Any

import can
import canopen
from canopen.objectdictionary import ObjectDictionary

from feeder.drivers.amplifier import (
    FLYBACK_SHAPES,
    Amplifier,
    AmplifierError,
    AmplifierLinkLost,
    AmplifierStatus,
    DriveSettings,
)
from feeder.drivers.canopen_codes import fault_names
from feeder.drivers.canopen_heartbeat import HostHeartbeat
from feeder.drivers.canopen_link import DEFAULT_HOST_ID, CanopenNodeLink
from feeder.errors import InputError
from feeder.protocol.eds import MODES, bit_mask

SETTINGS = ("Flyback shape", "Frequency", "Flyback time", "Amplitude")
"""The objects :meth:`CanopenAmplifier.apply` writes, in the order of ``_write_settings``' arguments."""

STATE_OBJECTS = (
    "Mode",
    "Offset",
    "Continuous",
    "Fault reset",
    "Fault word",
    "Step counter",
    "Status word",
    "Step command",
    "Command sequence",
    "Command acknowledge",
)
"""The axis' objects besides :data:`SETTINGS` the driver uses (one-axis EDS names)."""


class CanopenAmplifier(Amplifier):
    """Axis ``axis`` of CANopen node ``node_id`` on a python-can bus.

    The arguments but ``axis`` are :class:`CanopenNodeLink`'s: this driver opens its
    own link to the node.  To drive several axes of one node, open the link once and
    put one driver per axis on it (:meth:`on_link`, :func:`open_node_axes`).
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
        axis: int = 1,
    ) -> None:
        link = CanopenNodeLink(bus, node_id, eds, heartbeat_s, timeout_s, supervise_host, host_id, network)
        try:
            self._attach(link, axis)
        except InputError:
            link.close()
            raise

    @classmethod
    def on_link(cls, link: CanopenNodeLink, axis: int) -> CanopenAmplifier:
        """The driver of axis ``axis`` on an open ``link`` (closing it releases the link)."""
        driver = cls.__new__(cls)
        driver._attach(link, axis)
        return driver

    def _attach(self, link: CanopenNodeLink, axis: int) -> None:
        if not 1 <= axis <= link.axes:
            raise InputError("axis", f"CANopen node {link.node_id} has axes 1..{link.axes}, not {axis}")
        self.link, self.axis = link, axis
        self.node_id, self.node, self.network = link.node_id, link.node, link.network
        self.heartbeat_s, self.timeout_s = link.heartbeat_s, link.timeout_s
        self.who = f"CANopen node {link.node_id}" + (f" axis {axis}" if link.axes > 1 else "")
        self._names = {name: link.name(axis, name) for name in (*SETTINGS, *STATE_OBJECTS)}
        od = link.node.object_dictionary
        self._moving = bit_mask(od, self._names["Status word"], "moving")
        self._refused = bit_mask(od, self._names["Status word"], "refused")
        self._rpdo = link.node.rpdo[axis]
        self._feedback = link.feedback[axis]
        self._lock = threading.RLock()
        self._closed = False
        self._continuous = False  # a continuous run was started (by SDO) since the last RPDO command
        self._offset_mode = False  # this driver put the axis in ``off`` (hold_offset)
        link.acquire()

    @property
    def lost(self) -> str | None:
        """Why the node was declared lost, or None while it is healthy."""
        return self.link.lost

    @property
    def _host_heartbeat(self) -> HostHeartbeat | None:
        return self.link.host_heartbeat

    @property
    def emcy(self) -> str | None:
        """The latest EMCY naming this axis, until the node's error reset (or :meth:`clear_faults`)."""
        with self.link.changed:
            return self._feedback.emcy

    def alive(self) -> None:
        """The caller's control loop is making progress: the link's host heartbeat goes on
        (:class:`~feeder.drivers.canopen_heartbeat.HostHeartbeat`).  Cheap, any thread."""
        self.link.alive()

    # -- SDO and RPDO -----------------------------------------------------------

    def _sdo_write(self, name: str, value: int, lost_ok: bool = False) -> None:
        """Write this axis' object ``name`` (its one-axis EDS name); ``lost_ok``: see
        :meth:`.CanopenNodeLink.sdo_write`."""
        self.link.sdo_write(self._names[name], value, self.who, lost_ok=lost_ok)

    def _sdo_read(self, name: str) -> int:
        """Read this axis' object ``name`` (its one-axis EDS name)."""
        return self.link.sdo_read(self._names[name], self.who)

    def _command(self, count: int) -> None:
        """Send ``count`` by the axis' RPDO and wait for the node's acknowledge in its TPDO.
        A step (not a stop) first raises an EMCY of the axis not raised yet."""
        link, feedback = self.link, self._feedback
        with self._lock:
            link.check()
            if count:
                link.raise_emcy(self.axis)
            feedback.sequence = (feedback.sequence + 1) % 256
            sequence = feedback.sequence
            self._rpdo[self._names["Step command"]].raw = count
            self._rpdo[self._names["Command sequence"]].raw = sequence
            try:
                self._rpdo.transmit()
            except (can.CanError, OSError) as exc:  # the adapter's port is gone
                raise AmplifierLinkLost(f"{self.who}: {exc}") from exc
            with link.changed:
                acked = link.changed.wait_for(
                    lambda: feedback.ack == sequence or link.lost is not None, self.timeout_s
                )
                link.check()
                refused = feedback.status_word & self._refused
            if not acked:
                raise AmplifierLinkLost(f"{self.who}: step command not acknowledged")
            self._continuous = False
        if refused:
            state = self.status()
            reason = f"fault {', '.join(state.faults)}" if state.fault_word else f"mode {state.mode}"
            raise AmplifierError(f"{self.who}: step {count} refused ({reason})")

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
            self.link.raise_emcy(self.axis)
            self._sdo_write("Continuous", 1 if forward else -1)
            self._continuous = True

    def stop(self) -> None:
        self._command(0)

    def wait(self, timeout_s: float) -> bool:
        """Until the axis' TPDO shows it not moving; an EMCY of the axis (arriving meanwhile, or
        not raised yet) raises :class:`AmplifierError` at once."""
        link, feedback = self.link, self._feedback
        with link.changed:
            done = link.changed.wait_for(
                lambda: (
                    not feedback.status_word & self._moving or link.lost is not None or feedback.emcy_pending
                ),
                timeout_s,
            )
            link.check()
            link.raise_emcy(self.axis)
            return done

    def ground(self) -> None:
        """Mode = gnd; tried on a lost node too while it still beats (it may drive on)."""
        with self._lock:
            self._sdo_write("Mode", MODES.index("gnd"), lost_ok=True)
            if self._offset_mode:  # grounded: a later offset mode starts from 0 V, not from it
                self._offset_mode = False
                self._sdo_write("Offset", 0, lost_ok=True)

    def enable(self) -> None:
        with self._lock:
            self._offset_mode = False
            self._sdo_write("Mode", MODES.index("stp"))

    def hold_offset(self, volts: float) -> None:
        """``Offset`` (mV) first, then ``Mode`` = off unless this driver set it."""
        with self._lock:
            self._sdo_write("Offset", round(volts * 1000))
            if not self._offset_mode:
                self._sdo_write("Mode", MODES.index("off"))
                self._offset_mode = True

    def clear_faults(self) -> None:
        """Clear the axis' latched fault word (``Fault reset``) and the EMCY that reported it;
        the output stays grounded."""
        with self._lock:
            self._sdo_write("Fault reset", 1)
            self.link.forget_emcy(self.axis)

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

    def steps_played(self) -> tuple[int, bool]:
        """(the drive's step counter, False: it is never an estimate).

        From the axis' latest TPDO, without bus traffic, when its count is final: that TPDO
        acknowledges the last step command or stop (the node sent it after acting on the
        command), shows the axis not moving, and no continuous run was started since (it
        starts by SDO, unacknowledged by the TPDO).  That holds where the executor asks:
        after :meth:`wait` saw a burst end, after a :meth:`stop`'s acknowledge once the
        axis stood still.  Otherwise (still moving): one SDO read of ``Step counter``.
        """
        link, feedback = self.link, self._feedback
        with self._lock:
            with link.changed:
                link.check()
                final = (
                    feedback.ack == feedback.sequence
                    and not feedback.status_word & self._moving
                    and not self._continuous
                )
                counter = feedback.counter
            if not final:
                counter = self._sdo_read("Step counter")
        return counter, False

    @property
    def step_counter(self) -> int:
        """The step counter from the axis' latest TPDO (no bus traffic)."""
        with self.link.changed:
            return self._feedback.counter

    def close(self) -> None:
        """Release this axis; the last axis of the node releases the link (outputs are
        left alone: the node stops watching us first)."""
        if self._closed:
            return
        self._closed = True
        self.link.release()


def open_node_axes(
    bus: Mapping[str, Any],
    node_id: int,
    axes: Iterable[int] | None = None,
    eds: ObjectDictionary | None = None,
    network: canopen.Network | None = None,
    **options: Any,
) -> dict[int, CanopenAmplifier]:
    """One :class:`CanopenAmplifier` per axis (``axes``; default: all the EDS lists) of
    node ``node_id``, sharing one :class:`CanopenNodeLink` (options: its keywords)."""
    link = CanopenNodeLink(bus, node_id, eds, network=network, **options)
    try:
        numbers = range(1, link.axes + 1) if axes is None else axes
        return {number: CanopenAmplifier.on_link(link, number) for number in numbers}
    except InputError:
        link.close()
        raise
