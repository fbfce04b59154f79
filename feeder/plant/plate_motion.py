"""Plate motion in the plane: x, y translations of the rotation centre O and the turn θ (DESIGN §9).

The motion is a sequence of segments.  In a segment of duration T each axis
q ∈ (x, y, θ) moves as

    q(τ) = q₀ + v·τ + ½a·τ² + C·(cos κτ − 1),   0 ≤ τ ≤ T,

so constant-velocity ramps, constant accelerations (sampled plant signals) and
half-cosine flybacks are exact.  Velocities may jump between segments (the
corners of an ideal sawtooth).  Units: m, m/s, m/s² for x, y; rad, rad/s,
rad/s² for θ.  Positions start at zero: at t = 0 the plate frame (origin O) is
the lab frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feeder.errors import InputError


@dataclass(frozen=True)
class Segment:
    """One segment: duration (s); velocity at its start, acceleration and cosine amplitude per axis.

    velocity, accel, cosine: (v_x, v_y, Ω), (a_x, a_y, α), (C_x, C_y, C_θ);
    kappa: κ (rad/s) of the cosine term (0 when there is none).
    """

    duration_s: float
    velocity: tuple[float, float, float]
    accel: tuple[float, float, float] = (0.0, 0.0, 0.0)
    cosine: tuple[float, float, float] = (0.0, 0.0, 0.0)
    kappa: float = 0.0

    def position(self, tau: float) -> tuple[float, float, float]:
        """Displacement of each axis since the segment's start."""
        c = math.cos(self.kappa * tau) - 1.0
        v, a, k = self.velocity, self.accel, self.cosine
        return (v[0] * tau + 0.5 * a[0] * tau * tau + k[0] * c,
                v[1] * tau + 0.5 * a[1] * tau * tau + k[1] * c,
                v[2] * tau + 0.5 * a[2] * tau * tau + k[2] * c)  # fmt: skip

    def velocity_at(self, tau: float) -> tuple[float, float, float]:
        s = -self.kappa * math.sin(self.kappa * tau)
        v, a, k = self.velocity, self.accel, self.cosine
        return v[0] + a[0] * tau + k[0] * s, v[1] + a[1] * tau + k[1] * s, v[2] + a[2] * tau + k[2] * s

    def accel_at(self, tau: float) -> tuple[float, float, float]:
        c = -(self.kappa**2) * math.cos(self.kappa * tau)
        a, k = self.accel, self.cosine
        return a[0] + k[0] * c, a[1] + k[1] * c, a[2] + k[2] * c

    @property
    def smooth(self) -> bool:
        """Constant acceleration (no cosine term)."""
        return self.kappa == 0 or self.cosine == (0.0, 0.0, 0.0)

    @property
    def turns(self) -> bool:
        return self.velocity[2] != 0 or self.accel[2] != 0 or self.cosine[2] != 0


@dataclass(frozen=True)
class PlanarMotion:
    """Segments, the plate velocity before the first one, and segments per period (for poses)."""

    segments: tuple[Segment, ...]
    initial_velocity: tuple[float, float, float]
    segments_per_period: int


def sawtooth(
    stroke: tuple[float, float, float],
    frequency_hz: float,
    flyback_s: float,
    flyback_shape: str = "linear",
    periods: int = 1,
) -> PlanarMotion:
    """``periods`` sawtooth periods (flyback, then rise) on every axis with a non-zero stroke.

    stroke: (S_x m, S_y m, S_θ rad); a positive stroke moves the plate towards
    +x (+y) or turns it from +x towards +y during the slow rise (negative:
    backward).  Like :func:`feeder.plant.ideal_plate.sawtooth_motion` the motion
    starts at the top of a rise, the plate moving at the rise velocity and a
    stuck part moving with it, so each period ends with the plate back at its start.
    """
    if not (math.isfinite(frequency_hz) and frequency_hz > 0):
        raise InputError("frequency_hz", f"must be a positive number, got {frequency_hz!r}")
    if not (0 < flyback_s < 1 / frequency_hz):
        raise InputError("flyback_s", f"must lie in (0, period), got {flyback_s!r}")
    if periods < 1:
        raise InputError("periods", f"must be at least 1, got {periods}")
    t_r = 1.0 / frequency_hz - flyback_s
    s = tuple(float(v) for v in stroke)
    rise = Segment(t_r, (s[0] / t_r, s[1] / t_r, s[2] / t_r))
    if flyback_shape == "linear":
        fly = Segment(flyback_s, (-s[0] / flyback_s, -s[1] / flyback_s, -s[2] / flyback_s))
    elif flyback_shape == "half-cosine":
        fly = Segment(flyback_s, (0.0, 0.0, 0.0), cosine=(0.5 * s[0], 0.5 * s[1], 0.5 * s[2]),
                      kappa=math.pi / flyback_s)  # fmt: skip
    else:
        raise InputError("flyback_shape", f"expected linear or half-cosine, got {flyback_shape!r}")
    return PlanarMotion((fly, rise) * periods, rise.velocity, 2)


def sampled(velocity: np.ndarray, previous: tuple[float, float, float],
            sample_rate_hz: float) -> list[Segment]:  # fmt: skip
    """Segments between plate-velocity samples (3, n), acceleration held constant in each.

    previous: the velocity at the sample before the first (the plant's
    convention, :class:`feeder.plant.plant.Plant`): positions then follow the
    trapezoid rule, exact for the first-order-hold stack model.
    """
    v = np.asarray(velocity, dtype=float)
    dt = 1.0 / sample_rate_hz
    start = np.concatenate([np.asarray(previous, dtype=float)[:, None], v[:, :-1]], axis=1)
    accel = (v - start) * sample_rate_hz
    return [Segment(dt, (float(a), float(b), float(c)), (float(d), float(e), float(f)))
            for a, b, c, d, e, f in zip(*start, *accel, strict=True)]  # fmt: skip
