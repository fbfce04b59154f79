"""The plate's axes and their default amplifier wiring (DESIGN §9).

Data only: the plant, the planners, the drivers and the daemon all name the axes from here.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

AXES: tuple[str, ...] = ("x", "y", "theta")
"""x and y translations of the plate, θ its rotation about the centre O."""
DEFAULT_AXIS_MAP: Mapping[str, int] = MappingProxyType({"x": 1, "y": 2, "theta": 3})
"""Plate axis → amplifier axis: ANC300 axes 1–3, or CANopen amplifier axes (node node_id + n − 1
with the one-axis EDS, axis n of node node_id with the three-axis EDS); ``[plate] axis_map``
overrides it."""
MAX_AXIS = 7
"""Amplifier axes are numbered 1..MAX_AXIS: an ANC300 rack has 7 slots; firmware_sim has as many."""


def amplifier_node(node_id: int, axis: int, axes_per_node: int) -> tuple[int, int]:
    """CANopen wiring of amplifier axis ``axis`` (1-based) when the amplifier's first node is
    ``node_id`` and each node drives ``axes_per_node`` axes: (its node, its axis on that node)."""
    return node_id + (axis - 1) // axes_per_node, (axis - 1) % axes_per_node + 1
