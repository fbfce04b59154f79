"""What one step of each axis does to a part on the plate: predicted by the planar plant, learned online.

x and y: a translation step moves every part by the same ``step_m`` along the
axis (the 1-D model, DESIGN §4).  θ: a step turns the plate about O, and what
it does to a part depends on where it sits (docs/plant.md, the θ vector field):
inside the dead zone nothing; outside the part *orbits* O by ``orbit_rad``,
drifts radially by ``radial_m`` and *turns* by ``turn_rad`` per step.  The
turn also depends on the part's orientation β = ψ − φ relative to the radial
direction (a rectangle lying along the radius turns up to ~3× more than across it near the dead zone).

The seed is one period of :func:`feeder.plant.planar.simulate`
on the ideal sawtooth of each mode: x/y once per mode, θ on a grid of radii
and β (cached, :func:`seed_response`).  Online, each seed is multiplied by a
learned gain: one per (x|y, direction, mode); for θ one per radius bin, per
(direction, mode) and per quantity (orbit, turn), estimated by a Kalman filter
whose prior correlates neighbouring bins (so one burst at 1.6 mm also informs
1.4 mm and 1.8 mm, less so 3 mm).
"""

from __future__ import annotations

import bisect
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from feeder.errors import InputError
from feeder.plant.planar import PlanarPart, simulate
from feeder.plant.plate_motion import PlanarMotion, sawtooth
from feeder.plate_axes import AXES

log = logging.getLogger(__name__)

MODES = ("coarse", "fine")
"""Every axis' waveforms, coarse first; θ's turn a single part (and carry the others along)."""
ANCHOR_MODES = ("anchor", "anchor-fine")
"""θ's anchoring waveforms, coarse first (several parts on a CANopen drive,
:func:`feeder.daemon.plane.anchor_modes`): parts near O stay put while the others orbit, so the
pair strategy (:mod:`feeder.pose_pair`) orbits with these alone; θ's coarse and fine still turn
single parts.  A model without them orbits with coarse and fine too (:meth:`ResponseModel.orbit_modes`)."""
SEED_STD = 0.3
"""Prior relative uncertainty of every seed (1σ): the plant model within 30 %."""
BIN_CORRELATION_M = 0.5e-3
"""Correlation length of the θ gains over the radius (m)."""
MODEL_STD = 0.03
"""Relative scatter a single burst adds beyond the sensor (pose-dependence the table misses)."""
GATE_SIGMAS = 5.0
"""A burst whose effect lies further than this many σ from the prediction is not learned from
(σ² = the predicted effect's variance, at least the seed's :data:`SEED_STD`, plus the
measurement's): a reading of another burst's motion (frames lagging behind on a loaded
machine: a 2-step fine θ burst once "orbited" a part 0.24 rad and set gains of 228), not a
change of the plant.  The seed's floor keeps a confident filter open to real drift (up to
~1.5× the seed per burst).  Two bursts in a row beyond it whose ratios to the seed agree
within :data:`AGREE` are the plant, not a misreading: the prior is reopened around that ratio
(a real device's response may lie several times off the physics' seed)."""
AGREE = 0.25
"""Relative agreement of two gated bursts' ratios to the seed (same sign) that makes them real."""


@dataclass(frozen=True)
class AxisMode:
    """One waveform of one axis: a sawtooth of ``stroke`` (m for x, y; rad for θ) at frequency and flyback."""

    axis: str
    mode: str
    stroke: float
    frequency_hz: float
    flyback_s: float
    flyback_shape: str = "linear"

    def __post_init__(self) -> None:
        if self.axis not in AXES:
            raise InputError("axis", f"expected one of {', '.join(AXES)}, got {self.axis!r}")
        names = MODES + ANCHOR_MODES if self.axis == "theta" else MODES
        if self.mode not in names:
            raise InputError("mode", f"expected one of {', '.join(names)}, got {self.mode!r}")
        if not (math.isfinite(self.stroke) and self.stroke > 0):
            raise InputError("stroke", f"must be a positive number, got {self.stroke!r}")

    def motion(self, direction: int, steps: int) -> PlanarMotion:
        """The ideal plate motion of ``steps`` steps in ``direction`` (+1/−1)."""
        stroke = [0.0, 0.0, 0.0]
        stroke[AXES.index(self.axis)] = direction * self.stroke
        s = (stroke[0], stroke[1], stroke[2])
        return sawtooth(s, self.frequency_hz, self.flyback_s, self.flyback_shape, steps)


def _bracket(grid: Sequence[float], r: float) -> tuple[int, float]:
    """The cell ``i`` of a sorted grid (≥ 2 points) that holds ``r`` (the first or last cell
    beyond the ends) and ``r``'s place in it, 0–1, clipped."""
    i = min(max(bisect.bisect_left(grid, r) - 1, 0), len(grid) - 2)
    return i, min(max((r - grid[i]) / (grid[i + 1] - grid[i]), 0.0), 1.0)


@dataclass(frozen=True)
class TurnTable:
    """θ seed per step on a grid: radii (n,) m from O, betas (k,) rad over one symmetry period.

    orbit_rad, radial_m, turn_rad: (n, k), for a +θ step of the part at (r, 0) with ψ = β.
    period_rad: the part's physical symmetry (π rectangle, π/2 square, 0 disc: one β).
    """

    radii_m: tuple[float, ...]
    betas_rad: tuple[float, ...]
    orbit_rad: np.ndarray
    radial_m: np.ndarray
    turn_rad: np.ndarray
    period_rad: float

    def at(self, r_m: float, beta_rad: float) -> tuple[float, float, float]:
        """(orbit, radial, turn) per +θ step, bilinear in r and periodic in β; beyond the grid's
        ends, the end radius' values."""
        i, u = _bracket(self.radii_m, r_m)
        k = len(self.betas_rad)
        if k == 1:
            j0 = j1 = 0
            v = 0.0
        else:
            pos = (beta_rad % self.period_rad) / self.period_rad * k
            j0 = int(pos) % k
            j1 = (j0 + 1) % k
            v = pos - int(pos)

        def bilinear(table: np.ndarray) -> float:
            near, far = table[i], table[i + 1]  # as (1 − u)·near + u·far, then (1 − v)·[j0] + v·[j1]
            first = (1 - u) * near[j0] + u * far[j0]
            second = (1 - u) * near[j1] + u * far[j1]
            return float((1 - v) * first + v * second)

        return bilinear(self.orbit_rad), bilinear(self.radial_m), bilinear(self.turn_rad)


def physical_period_rad(part: PlanarPart) -> float:
    """The angle after which the part's footprint looks the same: π, π/2 (square), 0 (disc)."""
    if part.patch.shape == "disc":
        return 0.0
    return math.pi / 2 if part.patch.length_m == part.patch.width_m else math.pi


def translation_seed_m(part: PlanarPart, mode: AxisMode) -> float:
    """Step (m) of a translation mode: one period of the ideal sawtooth."""
    moved = simulate([part], mode.motion(+1, 1)).changes[0][0]
    return float(moved[AXES.index(mode.axis)])


@lru_cache(maxsize=16)
def turn_table(part: PlanarPart, mode: AxisMode, radii_m: tuple[float, ...], betas: int = 4) -> TurnTable:
    """θ seed per step on ``radii_m`` × ``betas`` orientations (cached: the simulation takes seconds)."""
    period = physical_period_rad(part)
    beta_grid = tuple(period * j / betas for j in range(betas)) if period > 0 else (0.0,)
    shape = (len(radii_m), len(beta_grid))
    orbit, radial, turn = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    for i, r in enumerate(radii_m):
        for j, beta in enumerate(beta_grid):
            placed = PlanarPart(part.patch, part.mass_kg, part.inertia_kg_m2, part.friction, (r, 0.0, beta))
            x, y, psi = simulate([placed], mode.motion(+1, 1)).poses[0][-1]
            # one period (the first differs from the steady one by < 1 %), in polar terms about O
            orbit[i, j] = math.atan2(y, x) if r > 0 else 0.0
            radial[i, j] = math.hypot(x, y) - r
            turn[i, j] = psi - beta
    return TurnTable(radii_m, beta_grid, orbit, radial, turn, period)


class GainFilter:
    """Kalman filter of seed gains g at bin radii (one bin for x/y): prediction = g(r)·seed.

    Prior g = 1 ± SEED_STD, correlated between bins as exp(−|Δr|/BIN_CORRELATION_M).
    A measurement ``measured = g(r)·predicted`` (g(r) linear between bins) with
    variance ``noise_var`` updates all bins through that correlation.
    """

    def __init__(self, centres_m: Sequence[float]) -> None:
        self.centres_m = tuple(float(c) for c in centres_m)
        centres = np.array(self.centres_m)
        self.gain = np.ones(centres.size)
        gap = np.abs(centres[:, None] - centres[None, :])
        self._correlation = np.exp(-gap / BIN_CORRELATION_M)
        self.covariance = SEED_STD**2 * self._correlation
        self.updates = 0
        self._refused: float | None = None  # the last burst's ratio to the seed, if it was gated

    def weights(self, r_m: float) -> np.ndarray:
        w = np.zeros(len(self.centres_m))
        if len(w) == 1:
            w[0] = 1.0
            return w
        i, u = _bracket(self.centres_m, r_m)
        w[i], w[i + 1] = 1 - u, u
        return w

    def at(self, r_m: float = 0.0) -> tuple[float, float]:
        """(gain, its std) at radius r: :meth:`weights` has two non-zeros, so in scalars (the
        pose planner asks ~150 times per burst it plans)."""
        g, c = self.gain, self.covariance
        if len(g) == 1:
            return float(g[0]), math.sqrt(max(float(c[0, 0]), 0.0))
        i, u = _bracket(self.centres_m, r_m)
        t = 1 - u
        variance = t * t * c[i, i] + t * u * (c[i, i + 1] + c[i + 1, i]) + u * u * c[i + 1, i + 1]
        return float(t * g[i] + u * g[i + 1]), math.sqrt(max(float(variance), 0.0))

    def update(self, r_m: float, predicted: float, measured: float, noise_var: float) -> bool:
        """Fold in ``measured`` = g(r)·``predicted`` (variance ``noise_var``); False (nothing
        changed) when it lies beyond :data:`GATE_SIGMAS` of the prediction, unless the burst
        before it was as far off, alike (:data:`AGREE`): then the prior is reopened around it."""
        h = self.weights(r_m) * predicted
        spread = float(h @ self.covariance @ h)
        s = spread + noise_var
        if s <= 0:
            return False
        innovation = measured - float(h @ self.gain)
        if innovation**2 > GATE_SIGMAS**2 * (max(spread, (SEED_STD * predicted) ** 2) + noise_var):
            earlier, self._refused = self._refused, measured / predicted if predicted else None
            if earlier is None or self._refused is None or not _agree(earlier, self._refused):
                return False
            # a second burst as far off, alike: the plant differs from the seed by that ratio
            self.covariance = (SEED_STD * self._refused) ** 2 * self._correlation
            s = float(h @ self.covariance @ h) + noise_var
        self._refused = None
        k = self.covariance @ h / s
        self.gain = self.gain + k * innovation
        self.covariance = self.covariance - np.outer(k, h @ self.covariance)
        self.covariance = 0.5 * (self.covariance + self.covariance.T)
        self.updates += 1
        return True


@dataclass(frozen=True)
class TurnStep:
    """Predicted effect of one θ step on a part: orbit about O (rad), radial drift (m), turn (rad), stds."""

    orbit_rad: float
    radial_m: float
    turn_rad: float
    turn_std_rad: float
    orbit_std_rad: float


class ResponseModel:
    """Seeded per-step response of every axis mode, refined online (see the module docstring).

    translation: {(axis, mode): seed step m} for x and y; turn: {mode: TurnTable} for θ.
    sensor_noise_m, sensor_noise_rad: 1σ of one pose reading.
    """

    def __init__(
        self,
        translation: dict[tuple[str, str], float],
        turn: dict[str, TurnTable],
        sensor_noise_m: float = 0.1e-6,
        sensor_noise_rad: float = 0.2e-3,
    ) -> None:
        self.translation = dict(translation)
        self.turn = dict(turn)
        self.sensor_noise_m = sensor_noise_m
        self.sensor_noise_rad = sensor_noise_rad
        self._gains: dict[str, GainFilter] = {}
        for (axis, mode), _ in self.translation.items():
            for d in (+1, -1):
                self._gains[_key(axis, d, mode)] = GainFilter([0.0])
        for mode, table in self.turn.items():
            for d in (+1, -1):
                for quantity in ("orbit", "turn"):
                    self._gains[_key("theta", d, mode, quantity)] = GainFilter(table.radii_m)

    def turn_range(self, mode: str, r_m: float) -> tuple[float, float]:
        """(smallest, largest) |turn| per step of ``mode`` over the orientations at radius r (learned)."""
        table = self.turn[mode]
        rates = [
            abs(self.turn_step(d, mode, r_m, 0.0, beta).turn_rad) for beta in table.betas_rad for d in (1, -1)
        ]
        return min(rates), max(rates)

    def modes(self, axis: str) -> list[str]:
        """The modes this model knows for ``axis`` among :data:`MODES`, coarse first (θ: those
        that turn a part; :meth:`orbit_modes`: those that orbit one while another stays)."""
        have = self.turn if axis == "theta" else {m for (a, m) in self.translation if a == axis}
        return [m for m in MODES if m in have]

    def orbit_modes(self) -> list[str]:
        """θ's modes the pair strategy holds a part near O with while the other orbits, coarse
        first: :data:`ANCHOR_MODES` when the model has them, else θ's coarse and fine."""
        return [m for m in ANCHOR_MODES if m in self.turn] or self.modes("theta")

    def learned(self, axis: str, direction: int, mode: str) -> bool:
        """Whether an x or y step along ``direction`` has been learned from a burst (or restored)."""
        return self._gains[_key(axis, direction, mode)].updates > 0

    def step_m(self, axis: str, direction: int, mode: str) -> tuple[float, float]:
        """(step, std) of one x or y step, m, along ``direction``."""
        gain, std = self._gains[_key(axis, direction, mode)].at()
        seed = self.translation[(axis, mode)]
        return gain * seed, std * seed

    def turn_step(self, direction: int, mode: str, x_m: float, y_m: float, psi_rad: float) -> TurnStep:
        """One θ step of the part at (x, y, ψ), in ``direction`` (mirror image of +θ for −1)."""
        r = math.hypot(x_m, y_m)
        beta = psi_rad - math.atan2(y_m, x_m)
        orbit, radial, turn = self.turn[mode].at(r, direction * beta)
        g_turn, s_turn = self._gains[_key("theta", direction, mode, "turn")].at(r)
        g_orbit, s_orbit = self._gains[_key("theta", direction, mode, "orbit")].at(r)
        return TurnStep(
            direction * g_orbit * orbit,
            radial,
            direction * g_turn * turn,
            abs(s_turn * turn),
            abs(s_orbit * orbit),
        )

    def predict(
        self,
        axis: str,
        direction: int,
        mode: str,
        steps: int,
        pose: tuple[float, float, float],
        scale: float = 1.0,
    ) -> tuple[float, float, float]:
        """Pose after ``steps`` steps (θ: stepped through the table; ``scale`` multiplies every step)."""
        x, y, psi = pose
        if axis != "theta":
            step, _ = self.step_m(axis, direction, mode)
            d = direction * steps * step * scale
            return (x + d, y, psi) if axis == "x" else (x, y + d, psi)
        for _ in range(steps):
            s = self.turn_step(direction, mode, x, y, psi)
            r, phi = math.hypot(x, y), math.atan2(y, x)
            r, phi = r + s.radial_m * scale, phi + s.orbit_rad * scale
            x, y, psi = r * math.cos(phi), r * math.sin(phi), psi + s.turn_rad * scale
        return x, y, psi

    def learn(
        self,
        axis: str,
        direction: int,
        mode: str,
        steps: int,
        before: tuple[float, float, float],
        after: tuple[float, float, float],
    ) -> None:
        """Fold in what a burst of ``steps`` did to one part (plate frame poses before and after)."""
        if steps <= 0:
            return
        if axis != "theta":
            seed = self.translation[(axis, mode)]
            moved = direction * (after[0] - before[0] if axis == "x" else after[1] - before[1])
            predicted = steps * seed
            noise = 2 * self.sensor_noise_m**2 + (MODEL_STD * predicted) ** 2
            if not self._gains[_key(axis, direction, mode)].update(0.0, predicted, moved, noise):
                _not_learned(_key(axis, direction, mode), predicted, moved)
            return
        table = self.turn[mode]
        # the seed's own prediction over the burst (gains 1), stepped through the table
        x, y, psi = before
        orbit_seed = turn_seed = 0.0
        for _ in range(steps):
            r, phi = math.hypot(x, y), math.atan2(y, x)
            o, rad, t = table.at(r, direction * (psi - phi))
            orbit_seed, turn_seed = orbit_seed + o, turn_seed + t
            r, phi = r + rad, phi + direction * o
            x, y, psi = r * math.cos(phi), r * math.sin(phi), psi + direction * t
        r_mid = 0.5 * (math.hypot(*before[:2]) + math.hypot(*after[:2]))
        turned = direction * (after[2] - before[2])
        orbited = direction * math.remainder(
            math.atan2(after[1], after[0]) - math.atan2(before[1], before[0]), 2 * math.pi
        )
        angle_noise = 2 * self.sensor_noise_rad**2
        key = _key("theta", direction, mode, "turn")
        if not self._gains[key].update(r_mid, turn_seed, turned, angle_noise + (MODEL_STD * turn_seed) ** 2):
            _not_learned(key, turn_seed, turned)
        if r_mid > 0:
            orbit_noise = 2 * (self.sensor_noise_m / r_mid) ** 2 + (MODEL_STD * orbit_seed) ** 2
            key = _key("theta", direction, mode, "orbit")
            if not self._gains[key].update(r_mid, orbit_seed, orbited, orbit_noise):
                _not_learned(key, orbit_seed, orbited)

    def restore(self, estimates: dict[str, Any]) -> int:
        """Take back gains learned earlier (:meth:`estimates_json`, e.g. kept by the daemon's
        store); keys or radius bins that no longer match are left at the seed.  The prior's
        correlation between bins is kept, scaled to the learned std.  Returns how many keys."""
        taken = 0
        for key, f in self._gains.items():
            saved = estimates.get(key)
            if not isinstance(saved, dict) or saved.get("radii_m") != list(f.centres_m):
                continue
            gain, std = np.asarray(saved["gain"], dtype=float), np.asarray(saved["gain_std"], dtype=float)
            if gain.shape != f.gain.shape or std.shape != f.gain.shape or not np.all(np.isfinite(gain)):
                continue
            correlation = f.covariance / SEED_STD**2
            f.gain, f.covariance = gain, correlation * np.outer(std, std)
            f.updates = int(saved.get("bursts", 0))
            taken += 1
        return taken

    def estimates_json(self) -> dict[str, object]:
        """Learned gains per key (θ per radius bin), their std and the number of bursts folded in."""
        out: dict[str, object] = {}
        for key, f in self._gains.items():
            out[key] = {
                "radii_m": list(f.centres_m),
                "gain": f.gain.tolist(),
                "gain_std": np.sqrt(np.clip(np.diag(f.covariance), 0, None)).tolist(),
                "bursts": f.updates,
            }
        return out


def _agree(a: float, b: float) -> bool:
    """Two ratios of the same sign within :data:`AGREE` of the larger."""
    return a * b > 0 and abs(a - b) <= AGREE * max(abs(a), abs(b))


def _not_learned(key: str, predicted: float, measured: float) -> None:
    log.warning("%s: a burst's effect %.4g is far off the prediction %.4g; not learned from "
                "(a reading of another motion?)", key, measured, predicted)  # fmt: skip


def _key(axis: str, direction: int, mode: str, quantity: str = "step") -> str:
    return f"{axis}/{'+' if direction > 0 else '-'}/{mode}/{quantity}"


def seed_response(part: PlanarPart, modes: Sequence[AxisMode], radii_m: Sequence[float]) -> ResponseModel:
    """A model seeded from the planar plant: every x/y mode's step, every θ mode's table on ``radii_m``."""
    translation: dict[tuple[str, str], float] = {}
    turn: dict[str, TurnTable] = {}
    for mode in modes:
        if mode.axis == "theta":
            turn[mode.mode] = turn_table(part, mode, tuple(float(r) for r in radii_m))
        else:
            step = translation_seed_m(part, mode)
            if step <= 0:
                raise InputError("stroke", f"the {mode.mode} {mode.axis} mode does not move the part")
            translation[(mode.axis, mode.mode)] = step
    return ResponseModel(translation, turn)
