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
1.4 mm and 1.8 mm, less so 3 mm; :mod:`feeder.pose_gain`).  A burst narrows a gain's spread
only when it is alike the burst before it (:data:`~feeder.pose_gain.CONFIRM_BURSTS`), and the
travel cuts take the largest gain one burst plausibly shows
(:meth:`~feeder.pose_gain.GainFilter.bound`).
"""

from __future__ import annotations

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
from feeder.pose_gain import MODEL_STD, SEED_STD, GainFilter, bracket

log = logging.getLogger(__name__)

MODES = ("coarse", "fine")
"""Every axis' waveforms, coarse first; θ's turn a single part (and carry the others along)."""
ANCHOR_MODES = ("anchor", "anchor-fine")
"""θ's anchoring waveforms, coarse first (several parts on a CANopen drive,
:func:`feeder.daemon.plane.anchor_modes`): parts near O stay put while the others orbit, so the
pair strategy (:mod:`feeder.pose_pair`) orbits with these alone; θ's coarse and fine still turn
single parts.  A model without them orbits with coarse and fine too (:meth:`ResponseModel.orbit_modes`)."""


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
        i, u = bracket(self.radii_m, r_m)
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
        self._radial_reach: dict[str, float] = {}
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
        """Whether an x or y step along ``direction`` has been confirmed by
        :data:`~feeder.pose_gain.CONFIRM_BURSTS` alike bursts (or restored so); one burst alone
        may have read another motion."""
        return self._gains[_key(axis, direction, mode)].confirmed

    def step_m(self, axis: str, direction: int, mode: str) -> tuple[float, float]:
        """(step, std) of one x or y step, m, along ``direction``."""
        gain, std = self._gains[_key(axis, direction, mode)].at()
        seed = self.translation[(axis, mode)]
        return gain * seed, std * seed

    def radial_reach_m(self, mode: str) -> float:
        """The largest radial drift (m) of one θ step of ``mode`` anywhere in its table (not learned)."""
        reach = self._radial_reach.get(mode)
        if reach is None:
            reach = self._radial_reach[mode] = float(np.max(np.abs(self.turn[mode].radial_m)))
        return reach

    def step_bound_m(self, axis: str, direction: int, mode: str) -> float:
        """The longest x or y step (m) along ``direction`` one burst plausibly makes: the seed times
        the gain's :meth:`~feeder.pose_gain.GainFilter.bound` (what the travel cuts take)."""
        return self._gains[_key(axis, direction, mode)].bound() * self.translation[(axis, mode)]

    def turn_step(
        self, direction: int, mode: str, x_m: float, y_m: float, psi_rad: float, bound: bool = False
    ) -> TurnStep:
        """One θ step of the part at (x, y, ψ), in ``direction`` (mirror image of +θ for −1);
        ``bound``: the largest plausible (orbit and turn at their gains'
        :meth:`~feeder.pose_gain.GainFilter.bound`, the radial drift, not learned, the seed's
        upper end), with the learned stds."""
        mean, largest = self._turn_steps(direction, mode, x_m, y_m, psi_rad, bound)
        return largest if largest is not None else mean

    def _turn_steps(
        self, direction: int, mode: str, x_m: float, y_m: float, psi_rad: float, bound: bool
    ) -> tuple[TurnStep, TurnStep | None]:
        """:meth:`turn_step`, and with ``bound`` its bound, from one look-up of the table and gains."""
        r = math.hypot(x_m, y_m)
        beta = psi_rad - math.atan2(y_m, x_m)
        orbit, radial, turn = self.turn[mode].at(r, direction * beta)
        turn_gains = self._gains[_key("theta", direction, mode, "turn")]
        orbit_gains = self._gains[_key("theta", direction, mode, "orbit")]
        g_turn, s_turn = turn_gains.at(r)
        g_orbit, s_orbit = orbit_gains.at(r)
        stds = abs(s_turn * turn), abs(s_orbit * orbit)
        mean = TurnStep(direction * g_orbit * orbit, radial, direction * g_turn * turn, *stds)
        if not bound:
            return mean, None
        b_turn, b_orbit = turn_gains.widened(g_turn, s_turn, r), orbit_gains.widened(g_orbit, s_orbit, r)
        high = 1 + 2 * SEED_STD
        return mean, TurnStep(direction * b_orbit * orbit, radial * high, direction * b_turn * turn, *stds)

    def predict(
        self,
        axis: str,
        direction: int,
        mode: str,
        steps: int,
        pose: tuple[float, float, float],
        scale: float = 1.0,
        bound: bool = False,
    ) -> tuple[float, float, float]:
        """Pose after ``steps`` steps (θ: stepped through the table; ``scale`` multiplies every step).
        ``bound``: each step the larger of that and the largest plausible step
        (:meth:`step_bound_m`, :meth:`turn_step`'s ``bound``), what the travel cuts take."""
        x, y, psi = pose
        if axis != "theta":
            step, _ = self.step_m(axis, direction, mode)
            step *= scale
            if bound:
                step = max(step, self.step_bound_m(axis, direction, mode))
            d = direction * steps * step
            return (x + d, y, psi) if axis == "x" else (x, y + d, psi)
        for _ in range(steps):
            if bound:
                mean, largest = self._turn_steps(direction, mode, x, y, psi, True)
                assert largest is not None
                s = _larger(mean, largest, scale)
                scale_step = 1.0
            else:
                s = self.turn_step(direction, mode, x, y, psi)
                scale_step = scale
            r, phi = math.hypot(x, y), math.atan2(y, x)
            r, phi = r + s.radial_m * scale_step, phi + s.orbit_rad * scale_step
            x, y, psi = r * math.cos(phi), r * math.sin(phi), psi + s.turn_rad * scale_step
        return x, y, psi

    def learn(
        self,
        axis: str,
        direction: int,
        mode: str,
        steps: int,
        before: tuple[float, float, float],
        after: tuple[float, float, float],
        burst: object = None,
    ) -> None:
        """Fold in what a burst of ``steps`` did to one part (plate frame poses before and after);
        ``burst``: the same for every part of one burst (:meth:`~feeder.pose_gain.GainFilter.update`)."""
        if steps <= 0:
            return
        if axis != "theta":
            seed = self.translation[(axis, mode)]
            moved = direction * (after[0] - before[0] if axis == "x" else after[1] - before[1])
            predicted = steps * seed
            noise = 2 * self.sensor_noise_m**2 + (MODEL_STD * predicted) ** 2
            if not self._gains[_key(axis, direction, mode)].update(0.0, predicted, moved, noise, burst):
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
        if not self._gains[key].update(
            r_mid, turn_seed, turned, angle_noise + (MODEL_STD * turn_seed) ** 2, burst
        ):
            _not_learned(key, turn_seed, turned)
        if r_mid > 0:
            orbit_noise = 2 * (self.sensor_noise_m / r_mid) ** 2 + (MODEL_STD * orbit_seed) ** 2
            key = _key("theta", direction, mode, "orbit")
            if not self._gains[key].update(r_mid, orbit_seed, orbited, orbit_noise, burst):
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
            f.restore_state(saved)
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
                **f.state_json(),
            }
        return out


def _larger(step: TurnStep, bound: TurnStep, scale: float) -> TurnStep:
    """Per quantity, the larger of ``step`` × ``scale`` and ``bound`` (signed like the larger)."""

    def larger(a: float, b: float) -> float:
        return a * scale if abs(a * scale) >= abs(b) else b

    return TurnStep(
        larger(step.orbit_rad, bound.orbit_rad),
        larger(step.radial_m, bound.radial_m),
        larger(step.turn_rad, bound.turn_rad),
        step.turn_std_rad,
        step.orbit_std_rad,
    )


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
