"""Cantilevers of the paper's Table II (rectangular, nominal dimensions; stiffness from the
unloaded resonance). Force = stiffness × deflection."""

from __future__ import annotations

import math
from dataclasses import dataclass

from feeder.errors import InputError


@dataclass(frozen=True)
class Cantilever:
    """A rectangular AFM cantilever (SI units)."""

    name: str
    stiffness_n_per_m: float
    length_m: float
    width_m: float
    thickness_m: float
    resonance_hz: float


CANTILEVERS: dict[str, Cantilever] = {
    "TL-FM": Cantilever("TL-FM", 2.08, 225e-6, 28e-6, 3e-6, 70.42e3),
    "NSC35": Cantilever("NSC35", 1.25, 130e-6, 35e-6, 2e-6, 105e3),
}
"""Table II: Nanosensors TL-FM and Ultrasharp NSC35/AlBS."""


def cantilever_stiffness(name: str | None = None, stiffness_n_per_m: float | None = None) -> float | None:
    """Stiffness (N/m) from an explicit value or a preset name (case-insensitive); None if neither."""
    if stiffness_n_per_m is not None:
        if not (math.isfinite(stiffness_n_per_m) and stiffness_n_per_m > 0):
            raise InputError("--stiffness", f"must be a positive number of N/m, got {stiffness_n_per_m!r}")
        return stiffness_n_per_m
    if name is None:
        return None
    for key, lever in CANTILEVERS.items():
        if key.lower() == name.strip().lower():
            return lever.stiffness_n_per_m
    raise InputError("--cantilever", f"unknown cantilever {name!r}; known: {', '.join(CANTILEVERS)}")
