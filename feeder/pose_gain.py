"""One learned gain of the pose response (a ratio to the plant's seed): a Kalman filter over
radius bins (one bin for x and y), its gate against misreadings, the agreement that confirms it,
and the largest gain one burst plausibly shows (:meth:`GainFilter.bound`), which the travel cuts
take.  :class:`~feeder.pose_response.ResponseModel` keeps one per axis, direction, mode (and, for
θ, quantity)."""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

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
"""Relative agreement of two bursts' ratios to the seed (same sign) that makes them alike: two gated
ones are real; two learned ones in a row confirm the gain (:data:`CONFIRM_BURSTS`)."""
CONFIRM_BURSTS = 2
"""A gain is *confirmed* (per radius bin: the bin nearest each burst) while its last this many
bursts learned from are alike (:data:`AGREE`, or within their measurement noise; the parts read
after one burst are one burst): one burst may read another motion (a frame of a burst's tail on
a loaded machine; the 5σ gate, at least the seed's 30 % wide, lets a reading of 0.3× the seed
through), and the misreadings seen were never alike twice in a row (the gate's reopening rests
on the same).  Until then a burst moves the gain but leaves its spread as it was, and one unlike
an earlier burst counts for no more than the seed (:data:`SEED_STD` of the prediction added to
its noise): one misread burst set 0.30 ± 0.03 against a truth of 0.72, and pulled a gain learned
from 9 bursts 6 % (4σ) off.  x and y steps are probed until confirmed once
(:data:`~feeder.pose_planner.PROBE_FRACTION`); the travel cuts take at least the seed's upper
end while a gain is not confirmed (:meth:`GainFilter.bound`)."""


def bracket(grid: Sequence[float], r: float) -> tuple[int, float]:
    """The cell ``i`` of a sorted grid (≥ 2 points) that holds ``r`` (the first or last cell
    beyond the ends) and ``r``'s place in it, 0–1, clipped."""
    i = min(max(bisect.bisect_left(grid, r) - 1, 0), len(grid) - 2)
    return i, min(max((r - grid[i]) / (grid[i + 1] - grid[i]), 0.0), 1.0)


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
        self.agreeing = [0] * centres.size
        """Per bin, the bursts learned from in a row nearest it, the latest included, each alike
        the one before it (the first counts 1; a gated burst: 0); confirmed from
        :data:`CONFIRM_BURSTS` on."""
        self.confirmed = False
        """Some bin was confirmed (or restored so): for x and y (one bin) the probe is lifted."""
        self._refused: tuple[float, object] | None = None  # the last gated burst's ratio, its burst
        self._last: list[tuple[float, float] | None] = [None] * centres.size  # per bin: ratio, std
        # per bin: the last burst learned from, whether alike the one before, whether it was unlike
        self._burst: list[tuple[object, bool, bool]] = [(None, False, False)] * centres.size

    def weights(self, r_m: float) -> np.ndarray:
        w = np.zeros(len(self.centres_m))
        if len(w) == 1:
            w[0] = 1.0
            return w
        i, u = bracket(self.centres_m, r_m)
        w[i], w[i + 1] = 1 - u, u
        return w

    def at(self, r_m: float = 0.0) -> tuple[float, float]:
        """(gain, its std) at radius r: :meth:`weights` has two non-zeros, so in scalars (the
        pose planner asks ~150 times per burst it plans)."""
        g, c = self.gain, self.covariance
        if len(g) == 1:
            return float(g[0]), math.sqrt(max(float(c[0, 0]), 0.0))
        i, u = bracket(self.centres_m, r_m)
        t = 1 - u
        variance = t * t * c[i, i] + t * u * (c[i, i + 1] + c[i + 1, i]) + u * u * c[i + 1, i + 1]
        return float(t * g[i] + u * g[i + 1]), math.sqrt(max(float(variance), 0.0))

    def nearest(self, r_m: float) -> int:
        """The bin (index) nearest r."""
        if len(self.centres_m) == 1:
            return 0
        i, u = bracket(self.centres_m, r_m)
        return i if u < 0.5 else i + 1

    def bound(self, r_m: float = 0.0) -> float:
        """The largest gain (signed like the gain) one burst plausibly shows at r: |g| + 2σ, σ the
        learned spread and a burst's own scatter (:data:`MODEL_STD`); while the gain is not
        confirmed (:data:`CONFIRM_BURSTS`) at least the seed's prior allows, 1 + 2 × 30 %: a
        misread burst cannot make the travel cuts trust a smaller gain."""
        return self.widened(*self.at(r_m), r_m)

    def widened(self, g: float, s: float, r_m: float = 0.0) -> float:
        """:meth:`bound` of the gain ``g`` ± ``s`` (:meth:`at` at ``r_m``)."""
        high = abs(g) + 2 * math.hypot(s, MODEL_STD * g)
        if self.agreeing[self.nearest(r_m)] < CONFIRM_BURSTS:
            high = max(high, 1 + 2 * math.hypot(SEED_STD, MODEL_STD))
        return math.copysign(high, g)

    def update(
        self, r_m: float, predicted: float, measured: float, noise_var: float, burst: object = None
    ) -> bool:
        """Fold in ``measured`` = g(r)·``predicted`` (variance ``noise_var``); False (nothing
        changed) when it lies beyond :data:`GATE_SIGMAS` of the prediction, unless an earlier
        burst was as far off, alike (:data:`AGREE`): then the prior is reopened around it.
        Until a burst is alike the one before it nearest the same bin (:data:`CONFIRM_BURSTS`),
        it moves the gain but not its spread, and one unlike an earlier burst counts for no more
        than the seed.  ``burst``: what the reading belongs to (the parts of one burst are
        readings of the same burst, counted once; None: a burst of its own)."""
        h = self.weights(r_m) * predicted
        spread = float(h @ self.covariance @ h)
        s = spread + noise_var
        if s <= 0:
            return False
        b = self.nearest(r_m)
        token = object() if burst is None else burst
        innovation = measured - float(h @ self.gain)
        ratio = (measured / predicted, math.sqrt(noise_var) / abs(predicted)) if predicted else None
        if innovation**2 > GATE_SIGMAS**2 * (max(spread, (SEED_STD * predicted) ** 2) + noise_var):
            earlier = self._refused
            refused = None if ratio is None else ratio[0]
            if earlier is None or earlier[1] is not token:
                self._refused = None if refused is None else (refused, token)
            if earlier is None or earlier[1] is token or refused is None or not _agree(earlier[0], refused):
                self.agreeing[b] = 0  # the gain is in doubt until learned bursts agree again
                return False
            # a second burst as far off, alike: the plant differs from the seed by that ratio
            self.covariance = (SEED_STD * refused) ** 2 * self._correlation
            s = float(h @ self.covariance @ h) + noise_var
            self.agreeing[b], alike = CONFIRM_BURSTS - 1, True  # alike the refused one: counts
            unlike = False
        elif self._burst[b][0] is token:  # another part of the burst just learned from
            _, alike, unlike = self._burst[b]
        else:
            last = self._last[b]
            alike = ratio is not None and last is not None and _alike(last, ratio)
            unlike = not alike and last is not None
        if unlike:
            s += (SEED_STD * predicted) ** 2  # unlike an earlier burst: no surer than the seed
        self._refused = None
        k = self.covariance @ h / s
        self.gain = self.gain + k * innovation
        if alike:
            self.covariance = self.covariance - np.outer(k, h @ self.covariance)
            self.covariance = 0.5 * (self.covariance + self.covariance.T)
        self.updates += 1
        if self._burst[b][0] is not token:
            self.agreeing[b] = self.agreeing[b] + 1 if alike else 1
            self._burst[b] = (token, alike, unlike)
            self._last[b] = ratio
        self.confirmed = self.confirmed or self.agreeing[b] >= CONFIRM_BURSTS
        return True

    def state_json(self) -> dict[str, object]:
        """What :meth:`restore_state` takes back besides the gains: the agreement so far, per bin."""
        last = [list(v) if v is not None and all(map(math.isfinite, v)) else None for v in self._last]
        return {"agreeing": list(self.agreeing), "confirmed": self.confirmed, "last_ratio": last}

    def restore_state(self, saved: dict[str, Any]) -> None:
        """Take back :meth:`state_json` (with ``bursts``, :meth:`ResponseModel.restore`).  A state
        kept before it existed: confirmed (the probe lifted) when learned from
        :data:`CONFIRM_BURSTS` bursts, no bin's agreement known (the travel cuts doubt the gain
        until two bursts agree)."""
        n = len(self.centres_m)
        agreeing = saved.get("agreeing")
        if not (isinstance(agreeing, list) and len(agreeing) == n):
            agreeing = [0] * n
        self.agreeing = [a if type(a) is int and a >= 0 else 0 for a in agreeing]
        confirmed = saved.get("confirmed")
        self.confirmed = confirmed if isinstance(confirmed, bool) else self.updates >= CONFIRM_BURSTS
        lasts = saved.get("last_ratio")
        self._last = (
            [_ratio_std(v) for v in lasts] if isinstance(lasts, list) and len(lasts) == n else [None] * n
        )


def _agree(a: float, b: float) -> bool:
    """Two ratios of the same sign within :data:`AGREE` of the larger."""
    return a * b > 0 and abs(a - b) <= AGREE * max(abs(a), abs(b))


def _ratio_std(saved: object) -> tuple[float, float] | None:
    """A stored [ratio, std] (:meth:`GainFilter.state_json`), or None."""
    if not (isinstance(saved, list) and len(saved) == 2 and all(type(v) in (int, float) for v in saved)):
        return None
    ratio, std = float(saved[0]), float(saved[1])
    return (ratio, std) if math.isfinite(ratio) and math.isfinite(std) else None


def _alike(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Two bursts' (ratio to the seed, its std) alike: :func:`_agree`, or within 3σ of each
    other (a burst of a few steps reads mostly the camera's noise)."""
    return _agree(a[0], b[0]) or abs(a[0] - b[0]) <= 3 * math.hypot(a[1], b[1])
