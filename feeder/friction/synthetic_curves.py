"""Realistic generated friction force curves with a known static-friction peak.

The paper's raw curves are not public, so examples and tests use curves made here. The
support moves at constant speed; the cantilever deflection (what an AFM records) is:

1. free approach: baseline offset + linear drift + white noise;
2. loading after contact: the part is pushed into the cantilever through a contact that
   is slightly compliant and softens before slipping, so the force rises as
   ``F = F_s·(t − a·t²/2)/(1 − a/2)`` with ``t = u/u_s`` (u: displacement since contact,
   ``a``: softening, the slope at the peak is (1 − a) of the initial one);
3. slip at ``F_s``: the force relaxes within a few samples to the kinetic level
   ``r·F_s``, then stick-slip ripple (a sawtooth of relative amplitude ``ripple``).

Deflection = force / stiffness + offset + drift + noise. Units SI.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CurveShape:
    """Parameters of a generated curve (SI; fractions are of the sample count or of F_s)."""

    samples: int = 1500
    free_fraction: float = 0.3
    loading_fraction: float = 0.3
    contact_stiffness_ratio: float = 0.8
    softening: float = 0.15
    kinetic_ratio: float = 0.8
    ripple: float = 0.03
    ripple_period_samples: int = 40
    slip_time_samples: float = 2.0
    noise_deflection_m: float = 1e-9
    drift_m: float = 20e-9
    offset_m: float = 150e-9


def synthetic_force_curve(
    peak_force_n: float, stiffness_n_per_m: float, shape: CurveShape = CurveShape(), seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """(support displacement, cantilever deflection) in metres for a part breaking loose at
    ``peak_force_n`` on a cantilever of ``stiffness_n_per_m``."""
    rng = np.random.default_rng(seed)
    n = shape.samples
    # displacement to reach the peak: deflection F_s/k through the contact compliance
    u_peak = peak_force_n / (stiffness_n_per_m * shape.contact_stiffness_ratio)
    step = u_peak / (shape.loading_fraction * n)
    displacement = np.arange(n) * step
    contact = shape.free_fraction * n * step
    u = displacement - contact
    t = np.clip(u / u_peak, 0.0, None)
    a = shape.softening
    force = peak_force_n * (t - a * t * t / 2) / (1 - a / 2)
    sliding = t > 1.0
    since_slip = (u[sliding] - u_peak) / step  # samples since the slip
    kinetic = shape.kinetic_ratio * peak_force_n
    relax = np.exp(-since_slip / shape.slip_time_samples)
    ripple = (
        shape.ripple
        * peak_force_n
        * ((since_slip % shape.ripple_period_samples) / shape.ripple_period_samples - 0.5)
    )
    force[sliding] = kinetic + (peak_force_n - kinetic) * relax + ripple * (1 - relax)
    drift = shape.drift_m * np.arange(n) / n
    noise = rng.normal(0.0, shape.noise_deflection_m, n)
    deflection = force / stiffness_n_per_m + shape.offset_m + drift + noise
    return displacement, deflection
