"""Two parts on one plate: hold one in the dead zone, orbit the other about O (docs/pose-control.md).

Translations move both parts equally, so only θ changes where part B sits
relative to part A (d = c_B − c_A).  With A *anchored* at a point a inside the
dead zone of θ's orbit modes (it neither moves nor turns; the anchoring family
:data:`~feeder.pose_response.ANCHOR_MODES` when the drive has it, while θ's
coarse and fine turn single parts), a θ burst orbits B
about O: d' = R(φ)(a + d) − a.  So d reaches d_t when |a + d| + δ = |a + d_t|
(δ: B's radial drift over the orbit, from the model) and φ is the angle from
a + d to a + d_t.  The plan: (1) translate so that A sits at that anchor,
(2) orbit B (coarse, aiming short, then fine), (3) translate both so that each
is within tolerance of its target.  Limits (refused by :func:`pair_refusal`):
the anchor must lie within the dead zone (the distance between the parts can
change by at most about twice its radius), B must orbit outside it, and the
parts' angles are not controlled: B's turn is tied to its orbit, so the pair
strategy leaves B's angle free (a NaN target angle; any angle for a disc) and A's
as it is.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from feeder.pose import Pose

if TYPE_CHECKING:
    from feeder.pose_planner import AxisBurst, Finish, PosePlanner

ANCHOR_SLACK = 0.2
"""An anchored part moves by less than this fraction of the tolerance during a θ burst (every orbit
mode; :meth:`PosePlanner.theta_burst` cuts a burst there) ..."""
ANCHOR_STEPS = 10
"""... of at least this many steps, each as large as twice the seed (the prior's pessimistic step)."""


def anchor_radius_m(planner: PosePlanner) -> float:
    """Largest grid radius up to which no θ orbit mode
    (:meth:`~feeder.pose_response.ResponseModel.orbit_modes`) moves or turns a part (their dead
    zone), m; θ's turning modes do not count."""
    model = planner.model
    modes = model.orbit_modes()
    if not modes:
        return 0.0
    best = 0.0
    for r in model.turn[modes[0]].radii_m:
        for mode in modes:
            for beta in model.turn[mode].betas_rad:
                for d in (1, -1):
                    s = model.turn_step(d, mode, r, 0.0, beta)
                    if (
                        2 * ANCHOR_STEPS * abs(s.orbit_rad) * r > ANCHOR_SLACK * planner.tolerance_m
                        or 2 * ANCHOR_STEPS * abs(s.turn_rad) > ANCHOR_SLACK * planner.tolerance_rad
                    ):
                        return best
        best = r
    return best


def _order(targets: dict[int, Pose]) -> tuple[int, int]:
    a, b = sorted(targets)
    return a - 1, b - 1


def _relative_error(poses: list[Pose], targets: dict[int, Pose]) -> tuple[float, float]:
    """(d − d_t): how far B sits from A off what the targets ask (m)."""
    ia, ib = _order(targets)
    a, b = poses[ia], poses[ib]
    ta, tb = targets[ia + 1], targets[ib + 1]
    return b[0] - a[0] - (tb[0] - ta[0]), b[1] - a[1] - (tb[1] - ta[1])


def _anchor(d: tuple[float, float], d_t: tuple[float, float], drift_m: float) -> tuple[float, float]:
    """Point a nearest O with |a + d_t| − |a + d| = drift (Newton from the bisector's foot)."""
    ax, ay = -(d[0] + d_t[0]) / 2, -(d[1] + d_t[1]) / 2  # midpoint of −d and −d_t
    ux, uy = d_t[0] - d[0], d_t[1] - d[1]
    norm = math.hypot(ux, uy)
    if norm == 0:
        return 0.0, 0.0
    ux, uy = ux / norm, uy / norm
    along = ax * ux + ay * uy  # foot of the perpendicular from O on the bisector
    ax, ay = along * ux, along * uy
    for _ in range(20):
        pt, pd = (ax + d_t[0], ay + d_t[1]), (ax + d[0], ay + d[1])
        nt, nd = math.hypot(*pt), math.hypot(*pd)
        f = nt - nd - drift_m
        gx, gy = pt[0] / nt - pd[0] / nd, pt[1] / nt - pd[1] / nd
        g2 = gx * gx + gy * gy
        if g2 == 0 or abs(f) < 1e-12:
            break
        ax, ay = ax - f * gx / g2, ay - f * gy / g2
    return ax, ay


def _orbit_plan(
    planner: PosePlanner, poses: list[Pose], targets: dict[int, Pose]
) -> tuple[tuple[float, float], float, str]:
    """(anchor for A, orbit angle B needs about O, mode) with B's predicted radial drift folded in."""
    ia, ib = _order(targets)
    a, b = poses[ia], poses[ib]
    ta, tb = targets[ia + 1], targets[ib + 1]
    d = (b[0] - a[0], b[1] - a[1])
    d_t = (tb[0] - ta[0], tb[1] - ta[1])
    coarse = planner.model.orbit_modes()[0]
    drift = 0.0
    anchor = _anchor(d, d_t, drift)
    for _ in range(3):  # the drift depends on the orbit, which depends on the anchor
        start = (anchor[0] + d[0], anchor[1] + d[1])
        end = (anchor[0] + d_t[0], anchor[1] + d_t[1])
        phi = math.remainder(math.atan2(end[1], end[0]) - math.atan2(start[1], start[0]), 2 * math.pi)
        drift = _drift(planner, (start[0], start[1], b[2]), phi, coarse)
        anchor = _anchor(d, d_t, drift)
    start = (anchor[0] + d[0], anchor[1] + d[1])
    end = (anchor[0] + d_t[0], anchor[1] + d_t[1])
    phi = math.remainder(math.atan2(end[1], end[0]) - math.atan2(start[1], start[0]), 2 * math.pi)
    return anchor, phi, coarse


def _drift(planner: PosePlanner, pose: Pose, phi: float, mode: str) -> float:
    """Radial drift (m) of a part orbiting by ``phi`` about O with ``mode``: drift per step × steps."""
    s = planner.model.turn_step(1 if phi > 0 else -1, mode, *pose)
    return 0.0 if s.orbit_rad == 0 else abs(phi / s.orbit_rad) * s.radial_m


def pair_refusal(planner: PosePlanner, targets: dict[int, Pose], poses: list[Pose]) -> str | None:
    """Why this pair of targets cannot be reached together from these poses, or None."""
    ia, ib = _order(targets)
    ta, tb = targets[ia + 1], targets[ib + 1]
    if planner.symmetry_rad > 0:
        if not math.isnan(tb[2]):
            return (
                f"part {ib + 1}'s angle cannot be chosen when two parts are placed together: its turn is "
                "tied to its orbit about O (move it without an angle; docs/pose-control.md)"
            )
        if not math.isnan(ta[2]) and abs(planner.angle_error(poses[ia], ta)) > planner.tolerance_rad:
            return (
                f"part {ia + 1} keeps its angle while part {ib + 1} is placed: turn it first on its own "
                "or move it without an angle"
            )
    size = planner.part.patch.radius_m
    if math.hypot(tb[0] - ta[0], tb[1] - ta[1]) < 2 * size:
        return f"the targets of parts {ia + 1} and {ib + 1} overlap (centres closer than {2 * size:.3g} m)"
    if math.hypot(*_relative_error(poses, targets)) <= planner.tolerance_m:
        return None  # as far apart as their targets (within the tolerance): translations will do
    if not planner.model.orbit_modes():
        return "no θ mode: translations move both parts alike"
    r_anchor = anchor_radius_m(planner)
    if r_anchor == 0:
        return (
            "no θ waveform holds a part near O (the dead zone that keeps one part in place while "
            "the other orbits): θ steps move both parts (docs/pose-control.md, two parts)"
        )
    anchor, _, coarse = _orbit_plan(planner, poses, targets)
    reach = math.hypot(*anchor)
    if reach > r_anchor:
        return (
            f"part {ib + 1} must orbit O while part {ia + 1} stays held at {reach:.3g} m from O, "
            f"but only parts within {r_anchor:.3g} m of O stay held: the distance between the parts "
            "cannot change that much"
        )
    a, b = poses[ia], poses[ib]
    radius = math.hypot(anchor[0] + b[0] - a[0], anchor[1] + b[1] - a[1])
    orbit = max(abs(planner.model.turn_step(d, coarse, radius, 0.0, 0.0).orbit_rad) for d in (1, -1))
    if orbit * radius < planner.tolerance_m:
        return (
            f"part {ib + 1} would orbit O at {radius:.3g} m, inside the dead zone where θ steps do "
            "not move it: the parts are too close together"
        )
    return None


def next_pair_burst(
    planner: PosePlanner, poses: list[Pose], targets: dict[int, Pose]
) -> AxisBurst | Finish | None:
    """Anchor A, orbit B until d = d_t (within the tolerance), then translate both (None: both within it)."""
    from feeder.pose_planner import AxisBurst, Finish

    ia, ib = _order(targets)
    a, b = poses[ia], poses[ib]
    ta, tb = targets[ia + 1], targets[ib + 1]
    rel = _relative_error(poses, targets)
    tol = planner.tolerance_m
    if max(math.hypot(a[0] - ta[0], a[1] - ta[1]), math.hypot(b[0] - tb[0], b[1] - tb[1])) <= tol:
        return None
    if math.hypot(*rel) > 0.5 * tol:  # each part then ends within half of it, plus a fine step's rounding
        orbit = _orbit_burst(planner, poses, targets, rel)
        if isinstance(orbit, AxisBurst) or math.hypot(*rel) > tol:
            return orbit
        # off by less than the tolerance and no orbit corrects it (d ≈ d_t: the anchor runs
        # off): translating both may still put each within it
    # both move alike now: the fine-step offset (up to 3 per axis) that leaves the larger error smallest
    goal = (ta[0] + 0.5 * rel[0], ta[1] + 0.5 * rel[1])
    if math.hypot(goal[0] - a[0], goal[1] - a[1]) > 3 * tol:
        return planner.translate_burst(poses, ia, goal, exact=True)
    fine = planner.model.modes("x")[-1]

    def shift(axis: str, n: int) -> float:
        return (
            math.copysign(planner.model.step_m(axis, 1 if n > 0 else -1, fine)[0] * abs(n), n) if n else 0.0
        )

    best = min(
        ((i, j) for i in range(-3, 4) for j in range(-3, 4)),
        key=lambda ij: max(
            math.hypot(a[0] + shift("x", ij[0]) - ta[0], a[1] + shift("y", ij[1]) - ta[1]),
            math.hypot(b[0] + shift("x", ij[0]) - tb[0], b[1] + shift("y", ij[1]) - tb[1]),
        ),
    )
    if best == (0, 0):
        return Finish(
            "unreachable",
            f"parts {ia + 1} and {ib + 1} are {math.hypot(*rel):.3g} m off relative "
            "to each other: fine steps cannot put both within the tolerance",
        )
    axis, n = ("x", best[0]) if best[0] else ("y", best[1])
    return AxisBurst(axis, 1 if n > 0 else -1, abs(n), fine)


def _orbit_burst(
    planner: PosePlanner, poses: list[Pose], targets: dict[int, Pose], rel: tuple[float, float]
) -> AxisBurst | Finish:
    """The burst that brings d towards d_t: A to its anchor, or B's orbit about O (or why not)."""
    from feeder.pose_planner import Finish

    ia, ib = _order(targets)
    a, b = poses[ia], poses[ib]
    ta, tb = targets[ia + 1], targets[ib + 1]
    tol = planner.tolerance_m
    # where A is will do if B's orbit from there ends within the tolerance (the anchor the
    # plan picks is ill-conditioned once d ≈ d_t: noise would send A back and forth)
    end = (a[0] + tb[0] - ta[0], a[1] + tb[1] - ta[1])
    r_anchor = anchor_radius_m(planner)
    if math.hypot(a[0], a[1]) <= r_anchor and abs(math.hypot(b[0], b[1]) - math.hypot(*end)) <= 0.5 * tol:
        phi = math.remainder(math.atan2(end[1], end[0]) - math.atan2(b[1], b[0]), 2 * math.pi)
        burst = planner.theta_burst(poses, ib, phi, anchored=(ia,), quantity="orbit")
        if burst is not None:
            return burst
    anchor, phi, _ = _orbit_plan(planner, poses, targets)
    if math.hypot(*anchor) > r_anchor:
        return Finish(
            "unreachable",
            f"parts {ia + 1} and {ib + 1} are off by {math.hypot(*rel):.3g} m "
            "relative to each other, and no anchor within the dead zone corrects that",
        )
    if math.hypot(anchor[0] - a[0], anchor[1] - a[1]) > 0.5 * tol:
        move = planner.translate_burst(poses, ia, anchor, exact=True)
        if not isinstance(move, Finish):  # else A is as close to the anchor as fine steps get it
            return move
    burst = planner.theta_burst(poses, ib, phi, anchored=(ia,), quantity="orbit")
    if burst is not None:
        return burst
    return Finish("unreachable", f"part {ib + 1} cannot orbit by {phi:.3g} rad within the travel")
