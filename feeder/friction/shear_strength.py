"""Interfacial shear strength τ = F / A_r (paper eq. 7, Tables V–VI) with its uncertainty band.

F is the mean of the measured static-friction forces, A_r the real contact area (from the
GW model or given). The band is first-order propagation of two relative uncertainties in
quadrature::

    Δτ/τ = √((s_F / F̄)² + (ΔA / A_r)²)

s_F is the sample standard deviation of the forces (ddof = 1; 0 for a single force): the
spread of one measurement, as the paper's ± figures describe a spread, not the standard
error of the mean. ΔA/A_r is the relative half-width of the real-area band.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from feeder.errors import InputError


@dataclass(frozen=True)
class ShearStrength:
    """τ and what it came from (SI units)."""

    tau_pa: float
    tau_band_pa: float
    mean_force_n: float
    force_spread_n: float
    force_count: int
    real_area_m2: float
    real_area_band_m2: tuple[float, float]


def shear_strength(
    forces_n: Sequence[float],
    real_area_m2: float,
    real_area_rel_band: float = 0.0,
    single_force_rel_scatter: float = 0.0,
) -> ShearStrength:
    """τ = mean(F)/A_r and its band from the force spread and the real-area band.

    With one force the spread is unknown: ``single_force_rel_scatter`` stands for it."""
    forces = np.asarray(forces_n, dtype=float)
    if forces.size == 0 or not np.all(np.isfinite(forces) & (forces > 0)):
        raise InputError("--force", "need at least one positive, finite force in newtons")
    if not (math.isfinite(real_area_m2) and real_area_m2 > 0):
        raise InputError("real_area_m2", f"must be a positive area, got {real_area_m2!r}")
    if not (math.isfinite(real_area_rel_band) and 0 <= real_area_rel_band < 1):
        raise InputError("--area-band", f"must be a fraction in [0, 1), got {real_area_rel_band!r}")
    mean = float(forces.mean())
    spread = float(forces.std(ddof=1)) if forces.size > 1 else 0.0
    tau = mean / real_area_m2
    scatter = spread / mean if forces.size > 1 else single_force_rel_scatter
    relative = math.hypot(scatter, real_area_rel_band)
    return ShearStrength(
        tau_pa=tau,
        tau_band_pa=tau * relative,
        mean_force_n=mean,
        force_spread_n=spread,
        force_count=int(forces.size),
        real_area_m2=real_area_m2,
        real_area_band_m2=(real_area_m2 * (1 - real_area_rel_band), real_area_m2 * (1 + real_area_rel_band)),
    )
