"""The plate's three axes (x, y, θ) on one amplifier: one driver per axis, one shared link.

- ANC300 (serial or TCP console): :func:`open_anc300_axes` puts one
  :class:`~feeder.drivers.anc300.Anc300Amplifier` per axis on one
  :class:`~feeder.drivers.anc300_link.Anc300Link` (its lock serialises the axes'
  commands); only a real ANC300's verbs are sent (the strict dialect).
- CANopen: :func:`open_canopen_axes` puts one
  :class:`~feeder.drivers.canopen.CanopenAmplifier` per axis on one
  :class:`canopen.Network`.  The EDS says how many axes a node has (A): amplifier
  axis n is axis (n − 1) mod A + 1 of node ``node_id`` + (n − 1) div A, as
  firmware_sim's ``--can-node-id-base`` and ``--can-eds`` lay them out.  With the
  default one-axis EDS that is node ``node_id`` + n − 1; with the three-axis EDS,
  axes 1–3 are the three axes of node ``node_id``.  The axes of one node share its
  link (one heartbeat, one SDO channel; a lost node faults all of them).

Both take the same ``axis_map`` (plate axis name → amplifier axis number) and
return an :class:`Axes`, a ``dict[str, Amplifier]`` that also stops and
grounds every axis at once and grounds them all when closed.
"""

from __future__ import annotations

import contextlib
import functools
import logging
from collections.abc import Mapping
from types import TracebackType
from typing import Any

import canopen

from feeder.drivers.amplifier import Amplifier, AmplifierError
from feeder.drivers.anc300 import Anc300Amplifier
from feeder.drivers.anc300_link import Anc300Link
from feeder.drivers.canopen import open_node_axes
from feeder.drivers.canopen_link import disconnect
from feeder.errors import InputError
from feeder.plate_axes import AXES, DEFAULT_AXIS_MAP, MAX_AXIS, amplifier_node
from feeder.protocol.eds import EDS_FILE, axis_count, object_dictionary

log = logging.getLogger(__name__)


def check_axis_map(axis_map: Mapping[str, int], field: str = "axis_map") -> dict[str, int]:
    """``axis_map`` checked: plate axes of :data:`AXES`, distinct numbers in 1..7."""
    unknown = sorted(set(axis_map) - set(AXES))
    if unknown:
        raise InputError(field, f"unknown plate axis {unknown[0]!r} (expected {', '.join(AXES)})")
    numbers = list(axis_map.values())
    for name, number in axis_map.items():
        if isinstance(number, bool) or not isinstance(number, int) or not 1 <= number <= MAX_AXIS:
            raise InputError(f"{field}.{name}", f"expected an axis number 1..{MAX_AXIS}, got {number!r}")
    if len(set(numbers)) != len(numbers):
        raise InputError(field, f"two plate axes on one amplifier axis: {dict(axis_map)}")
    if not axis_map:
        raise InputError(field, "no axis")
    return dict(axis_map)


class Axes(dict[str, Amplifier]):
    """The plate's axes by name (``"x"``, ``"y"``, ``"theta"``): a dict of drivers.

    :meth:`stop` and :meth:`ground` act on every axis (each axis is tried even when
    another fails; the first error is raised after).  :meth:`close` grounds every
    axis (the safe state), then releases the drivers and the shared link.
    """

    def __init__(self, drivers: Mapping[str, Amplifier], close_link: Any = None) -> None:
        super().__init__(drivers)
        self._close_link = close_link
        self._closed = False

    def stop(self) -> None:
        """Stop every axis."""
        self._each(lambda amp: amp.stop())

    def ground(self) -> None:
        """Ground every axis."""
        self._each(lambda amp: amp.ground())

    def _each(self, action: Any) -> None:
        first: AmplifierError | None = None
        for name, amp in self.items():
            try:
                action(amp)
            except AmplifierError as exc:
                log.warning("axis %s: %s", name, exc)
                first = first or exc
        if first is not None:
            raise first

    def close(self) -> None:
        """Ground every axis (best effort: a lost link cannot), release drivers and link."""
        if self._closed:
            return
        with contextlib.suppress(AmplifierError):
            self.ground()
        self.release()

    def release(self) -> None:
        """Release the drivers and the shared link without touching the outputs (a link
        that may lead to another device now, e.g. a restarted simulator's old pty)."""
        if self._closed:
            return
        self._closed = True
        for amp in self.values():
            amp.close()
        if self._close_link is not None:
            self._close_link()

    def __enter__(self) -> Axes:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def open_anc300_axes(link: Anc300Link, axis_map: Mapping[str, int] = DEFAULT_AXIS_MAP) -> Axes:
    """One :class:`Anc300Amplifier` per plate axis on the shared ``link`` (ANC300 axes 1–3 by default)."""
    axes = check_axis_map(axis_map)
    return Axes({name: Anc300Amplifier(link, axis=number) for name, number in axes.items()}, link.close)


def open_canopen_axes(
    bus: Mapping[str, Any],
    axis_map: Mapping[str, int] = DEFAULT_AXIS_MAP,
    node_id: int = 1,
    eds: str = EDS_FILE,
    **options: Any,
) -> Axes:
    """One :class:`~feeder.drivers.canopen.CanopenAmplifier` per plate axis on one shared network.

    bus: python-can keyword arguments; node_id: the node of amplifier axis 1; eds: the
    nodes' EDS (a packaged EDS's name or a path): with A axes per node, amplifier axis n
    is axis (n − 1) mod A + 1 of node ``node_id`` + (n − 1) div A; options:
    :class:`~feeder.drivers.canopen.CanopenNodeLink`'s (heartbeat_s, timeout_s,
    supervise_host, ...).
    """
    axes = check_axis_map(axis_map)
    per_node = axis_count(object_dictionary(node_id, eds))
    last_node, _ = amplifier_node(node_id, max(axes.values()), per_node)
    if not 1 <= node_id <= last_node <= 127:
        raise InputError("node_id", f"node ids {node_id}..{last_node} for axes {axes} leave CANopen's 1..127")
    nodes: dict[int, dict[str, int]] = {}
    for name, number in axes.items():
        node, axis = amplifier_node(node_id, number, per_node)
        nodes.setdefault(node, {})[name] = axis
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.1  # close() waits at most this long for the receiver
    network.connect(**dict(bus))
    drivers: dict[str, Amplifier] = {}
    with contextlib.ExitStack() as undo:  # a node that does not answer: release the others
        undo.callback(disconnect, network)
        for node, members in nodes.items():
            opened = open_node_axes(
                bus, node, members.values(), object_dictionary(node, eds), network=network, **options
            )
            for driver in opened.values():
                undo.callback(driver.close)
            drivers.update({name: opened[number] for name, number in members.items()})
        undo.pop_all()
    return Axes(drivers, functools.partial(disconnect, network))
