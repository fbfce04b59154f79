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
is within tolerance of its target.  One orbit changes the distance between the
parts by at most 2·r_a·|d_t − d|/(|d| + |d_t|) (r_a: the dead zone's radius),
only as the line joining them turns; when the anchor lies beyond the dead zone,
a *length leg* first makes |d| = |d_t| (A held :data:`LEG_REACH`·r_a from O,
the line turned), and the plan turns it back.  Limits (refused by
:func:`pair_refusal`): the distance can change by at most ~2·LEG_REACH·r_a,
B must orbit where a step moves it, and the
parts' angles are not controlled: B's turn is tied to its orbit, so the pair
strategy leaves B's angle free (a NaN target angle; any angle for a disc) and A's
as it is.
"""

from __future__ import annotations

import math
from dataclasses import replace

from feeder.pose import Pose
from feeder.pose_burst import AxisBurst, Finish, carry_refusal
from feeder.pose_planner import PosePlanner
from feeder.pose_turns import USEFUL_ORBIT

ANCHOR_SLACK = 0.2
"""An anchored part moves by less than this fraction of the tolerance during a θ burst (every orbit
mode; :meth:`~feeder.pose_turns.TurnPlanner.theta_burst` cuts a burst there) ..."""
ANCHOR_STEPS = 10
"""... of at least this many steps, each as large as twice the seed (the prior's pessimistic step)."""
PAST = 2.0
"""A backward orbit aims this many tolerances (at B) past its end, so that the pair's last θ burst
is forward.  After backward steps θ's output rests at the top of its waveform, and grounding it
(done is checked grounded, docs/daemon.md) turns the plate about O with both parts stuck to it:
that turns d, which no translation corrects (a CANopen pair 1.1 mm apart read 2.3–4.3 µm off
after every ground).  After forward steps it rests at 0 V, where the ground leaves it."""
LEG_REACH = 0.5
"""A length leg holds A this fraction of the dead zone's radius from O (drift aside), leaving the
rest as margin for B's radial drift: the distance between the parts changes by up to
2 × LEG_REACH × r_a in one leg."""


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
    planner: PosePlanner, d: tuple[float, float], d_t: tuple[float, float], psi: float
) -> tuple[tuple[float, float], float]:
    """(anchor for A, orbit angle B needs about O) to bring d to d_t, with B's predicted radial
    drift over the orbit (B at angle ``psi``): the anchor nearest O."""

    def orbit(at: tuple[float, float]) -> float:  # B's orbit (rad) with A held at ``at``
        return _angle((at[0] + d[0], at[1] + d[1]), (at[0] + d_t[0], at[1] + d_t[1]))

    anchor = _anchor(d, d_t, 0.0)
    for _ in range(3):  # the drift depends on the orbit, which depends on the anchor
        drift = _drift(planner, (anchor[0] + d[0], anchor[1] + d[1], psi), orbit(anchor))
        anchor = _anchor(d, d_t, drift)
    return anchor, orbit(anchor)


def _length_leg(d: tuple[float, float], d_t: tuple[float, float], reach: float) -> tuple[float, float] | None:
    """The offset d_m as long as d_t whose plan from d puts the anchor ``reach`` from O (drift
    aside): d turned towards d_t's side by the least angle that does (|d_m − d| =
    ||d_t|² − |d|²| / (2·reach)); None when no angle does (||d_t| − |d|| > 2·reach)."""
    n, n_t = math.hypot(*d), math.hypot(*d_t)
    span = abs(n_t * n_t - n * n) / (2 * reach)
    cos_gamma = (n_t * n_t + n * n - span * span) / (2 * n_t * n)
    if cos_gamma < -1:
        return None
    gamma = math.copysign(math.acos(min(cos_gamma, 1.0)), _angle(d, d_t))
    c, s = math.cos(gamma), math.sin(gamma)
    return n_t / n * (c * d[0] - s * d[1]), n_t / n * (s * d[0] + c * d[1])


def _pair_plan(
    planner: PosePlanner, poses: list[Pose], targets: dict[int, Pose]
) -> tuple[tuple[float, float], float, bool] | None:
    """(anchor for A, B's orbit about O, whether it is a length leg): the plan that brings d to
    d_t, or, when its anchor lies beyond the dead zone (|d| must change along the line joining
    the parts), the length leg that makes |d| = |d_t| with A :data:`LEG_REACH` of the dead
    zone from O (the line joining them turns; the plan then turns it back from an anchor near
    O).  None: neither anchor lies within the dead zone."""
    ia, ib = _order(targets)
    a, b = poses[ia], poses[ib]
    ta, tb = targets[ia + 1], targets[ib + 1]
    d = (b[0] - a[0], b[1] - a[1])
    d_t = (tb[0] - ta[0], tb[1] - ta[1])
    r_anchor = anchor_radius_m(planner)
    anchor, phi = _orbit_plan(planner, d, d_t, b[2])
    if math.hypot(*anchor) <= r_anchor:
        return anchor, phi, False
    d_m = _length_leg(d, d_t, LEG_REACH * r_anchor)
    if d_m is None:
        return None
    anchor, phi = _orbit_plan(planner, d, d_m, b[2])
    return (anchor, phi, True) if math.hypot(*anchor) <= r_anchor else None


def _length_orbit(a: Pose, b: Pose, length: float) -> float | None:
    """The least orbit (rad) of B about O after which it lies ``length`` from A held where it
    is, or None (none does, or A is at O)."""
    r_a, r_b = math.hypot(a[0], a[1]), math.hypot(b[0], b[1])
    if r_a == 0 or r_b == 0:
        return None
    cos_chi = (r_b * r_b + r_a * r_a - length * length) / (2 * r_b * r_a)  # angle at O between A and B'
    if abs(cos_chi) > 1:
        return None
    chi = math.acos(cos_chi)
    start = math.atan2(a[1], a[0]) - math.atan2(b[1], b[0])
    return min((math.remainder(start + s * chi, 2 * math.pi) for s in (1, -1)), key=abs)


def _angle(start: tuple[float, float], end: tuple[float, float]) -> float:
    """Angle (rad, within ±π) from ``start`` to ``end`` about O."""
    return math.remainder(math.atan2(end[1], end[0]) - math.atan2(start[1], start[0]), 2 * math.pi)


def _path(burst: AxisBurst | Finish) -> AxisBurst | Finish:
    """A translation of both parts to an anchor or back to their targets, marked as a leg of the
    pair's path: A is moved again each time B's radius misses (once or twice per orbit, 2–6 µm,
    either way), and a pair's way out and back, x and y alternating, spent the daemon's
    reversals (a CANopen pair ended "oscillating" after 13, on its way)."""
    return replace(burst, path=True) if isinstance(burst, AxisBurst) else burst


def _orbit(
    planner: PosePlanner, poses: list[Pose], ia: int, ib: int, phi: float, targets: dict[int, Pose]
) -> AxisBurst | Finish | None:
    """B's orbit burst by up to ``phi`` with A anchored (its angle kept only when held: a pair
    whose A is held at any angle had its bursts cut 2.2× shorter by A's turn, 0.02° each, and
    each burst costs A's re-anchoring: 117–131 bursts, 160–170 s for a pair on the CAN plane)."""
    held = not math.isnan(targets[ia + 1][2])
    return planner.turns.theta_burst(poses, ib, phi, anchored=(ia,), quantity="orbit", anchored_angles=held)


def _ending_forward(phi: float, radius_m: float, tolerance_m: float) -> float:
    """The orbit (rad) to ask for B at ``radius_m`` from O to end ``phi`` away: forward as it is,
    backward :data:`PAST` tolerances further (the forward orbit back ends the pair's θ)."""
    return phi if phi >= 0 else phi - PAST * tolerance_m / max(radius_m, 1e-9)


def _drift(planner: PosePlanner, pose: Pose, phi: float) -> float:
    """Radial drift (m) of a part orbiting by ``phi`` about O with the coarse orbit mode: drift
    per step × steps."""
    s = planner.model.turn_step(1 if phi > 0 else -1, planner.model.orbit_modes()[0], *pose)
    return 0.0 if s.orbit_rad == 0 else abs(phi / s.orbit_rad) * s.radial_m


def pair_refusal(planner: PosePlanner, targets: dict[int, Pose], poses: list[Pose]) -> str | None:
    """Why this pair of targets cannot be reached together from these poses, or None."""
    ia, ib = _order(targets)
    ta, tb = targets[ia + 1], targets[ib + 1]
    if planner.symmetry_rad > 0:
        if not math.isnan(tb[2]):
            return (
                f"part {ib + 1}'s angle cannot be chosen when two parts are placed together: its turn is "
                f"tied to its orbit about O (place it without an angle, or let it go: feeder release --part "
                f"{ib + 1}; docs/pose-control.md)"
            )
        if not math.isnan(ta[2]) and abs(planner.turns.angle_error(poses[ia], ta)) > planner.tolerance_rad:
            return (
                f"part {ia + 1} keeps its angle while part {ib + 1} is placed: turn it first on its own "
                f"or move it without an angle (or let it go: feeder release --part {ia + 1})"
            )
    size = planner.part.patch.radius_m
    if math.hypot(tb[0] - ta[0], tb[1] - ta[1]) < 2 * size:
        return f"the targets of parts {ia + 1} and {ib + 1} overlap (centres closer than {2 * size:.3g} m)"
    rel = _relative_error(poses, targets)
    if math.hypot(*rel) <= planner.tolerance_m:
        return None  # as far apart as their targets (within the tolerance): translations will do
    if not planner.model.orbit_modes():
        return "no θ mode: translations move both parts alike"
    r_anchor = anchor_radius_m(planner)
    if r_anchor == 0:
        return (
            "no θ waveform holds a part near O (the dead zone that keeps one part in place while "
            "the other orbits): θ steps move both parts (docs/pose-control.md, two parts)"
        )
    plan = _pair_plan(planner, poses, targets)
    if plan is None:
        d = math.hypot(tb[0] - ta[0] + rel[0], tb[1] - ta[1] + rel[1])
        d_t = math.hypot(tb[0] - ta[0], tb[1] - ta[1])
        reach = LEG_REACH * r_anchor
        return (
            f"part {ib + 1} must orbit O while part {ia + 1} stays held, but only parts within "
            f"{r_anchor:.3g} m of O stay held: the distance between the parts cannot change that much "
            f"(from {d:.3g} m to {d_t:.3g} m; one orbit changes it by at most ~2·{reach:.3g} = "
            f"{2 * reach:.3g} m, with part {ia + 1} held {reach:.3g} m from O)"
        )
    anchor, phi, _ = plan
    # B's orbit from where A at the anchor puts it: some orbit mode must move it by a step
    # theta_burst will use (USEFUL_ORBIT of the tolerance), fine steps included
    a, b = poses[ia], poses[ib]
    start = (anchor[0] + b[0] - a[0], anchor[1] + b[1] - a[1], b[2])
    radius = math.hypot(start[0], start[1])
    direction = 1 if phi > 0 else -1
    modes = planner.model.orbit_modes()
    step = max(abs(planner.model.turn_step(direction, m, *start).orbit_rad) for m in modes)
    useful = USEFUL_ORBIT * planner.tolerance_m
    if step * radius < useful:
        return (
            f"part {ib + 1} would orbit O at {radius:.3g} m, in the dead zone: θ's orbit steps move it "
            f"by {step * radius:.3g} m at most, less than the {useful:.3g} m a step must move it by: the "
            "parts are too close together"
        )
    return None


def next_pair_burst(
    planner: PosePlanner, poses: list[Pose], targets: dict[int, Pose]
) -> AxisBurst | Finish | None:
    """Anchor A, orbit B until d = d_t (within the tolerance), then translate both (None: both within it)."""
    ia, ib = _order(targets)
    a, b = poses[ia], poses[ib]
    ta, tb = targets[ia + 1], targets[ib + 1]
    rel = _relative_error(poses, targets)
    off = math.hypot(*rel)
    tol = planner.tolerance_m
    if max(math.hypot(a[0] - ta[0], a[1] - ta[1]), math.hypot(b[0] - tb[0], b[1] - tb[1])) <= tol:
        return None
    goal = (ta[0] - 0.5 * rel[0], ta[1] - 0.5 * rel[1])  # A there: A and B each half of rel off
    if off > 0.5 * tol:  # each part then ends within half of it, plus a fine step's rounding
        orbit = _orbit_burst(planner, poses, targets, rel)
        if isinstance(orbit, AxisBurst):
            return orbit
        if off > 2 * tol:
            # no orbit corrects it (B's orbit failed where A went for it, or a leg turned the
            # line): the move ends with why, both parts first put back about their targets
            # (they ended 140–470 µm off, at the anchor, where the orbit had failed)
            if math.hypot(goal[0] - a[0], goal[1] - a[1]) > tol:
                back = _path(planner.translate_burst(poses, ia, goal, exact=True))
                if isinstance(back, AxisBurst):
                    return back
            return orbit
        # off by less than twice the tolerance and no orbit corrects it (d ≈ d_t: the anchor
        # runs off; or B cannot orbit there): translating both, each half of it off, may still
        # put each within it (a pair 0.9 mm apart ended 260 µm off both targets, at the anchor)
    # both move alike now: the fine-step offset (up to 3 per axis) that leaves the larger error smallest
    if math.hypot(goal[0] - a[0], goal[1] - a[1]) > 3 * tol:
        return _path(planner.translate_burst(poses, ia, goal, exact=True))
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
            f"parts {ia + 1} and {ib + 1} are {off:.3g} m off relative "
            "to each other: fine steps cannot put both within the tolerance",
        )
    axis, n = ("x", best[0]) if best[0] else ("y", best[1])
    direction = 1 if n > 0 else -1
    cut, by = planner.travel_cut(poses, axis, direction, fine, abs(n))  # like every burst
    if cut < 1:
        moving = f"moving parts {ia + 1} and {ib + 1} further in {'+' if direction > 0 else '−'}{axis}"
        k = ia if by is None else by
        return Finish("unreachable", carry_refusal(planner.travel, moving, k, poses[k]))
    return AxisBurst(axis, direction, cut, fine)


def _orbit_burst(
    planner: PosePlanner, poses: list[Pose], targets: dict[int, Pose], rel: tuple[float, float]
) -> AxisBurst | Finish:
    """The burst that brings d towards d_t: A to its anchor, or B's orbit about O (or why not)."""
    ia, ib = _order(targets)
    a, b = poses[ia], poses[ib]
    ta, tb = targets[ia + 1], targets[ib + 1]
    tol = planner.tolerance_m
    # where A is will do if B's orbit from there ends within half the tolerance of d_t's radius
    # and at least halves |d − d_t| (the anchor the plan picks is ill-conditioned once d ≈ d_t:
    # noise would send A back and forth; a radial miss of 0.4 tolerances with d 0.5 off had a
    # fine orbit step flip d around d_t for ever).  The predicted drift is left out: the coarse
    # mode's, it spoils the fine end of an orbit (tests/test_pose_planner.py's pairs)
    end = (a[0] + tb[0] - ta[0], a[1] + tb[1] - ta[1])
    phi = _angle((b[0], b[1]), end)
    r_anchor = anchor_radius_m(planner)
    miss = math.hypot(*end) - math.hypot(b[0], b[1])  # how far B's radius is off the end's
    if math.hypot(a[0], a[1]) <= r_anchor and abs(miss) <= min(0.5 * tol, 0.5 * math.hypot(*rel)):
        phi = _ending_forward(phi, math.hypot(b[0], b[1]), tol)
        burst = _orbit(planner, poses, ia, ib, phi, targets)
        if burst is not None:
            return burst
    plan = _pair_plan(planner, poses, targets)
    if plan is None or (plan[2] and math.hypot(*rel) <= tol):  # within it: translating may do
        return Finish(
            "unreachable",
            f"parts {ia + 1} and {ib + 1} are off by {math.hypot(*rel):.3g} m "
            "relative to each other, and no anchor within the dead zone corrects that",
        )
    anchor, phi, leg = plan
    if leg and math.hypot(a[0], a[1]) <= r_anchor:
        # a length leg from where A is, unless it asks for a longer orbit than the plan's
        # (the plan's anchor moves with d as B orbits: A would chase it)
        here = _length_orbit(a, b, math.hypot(tb[0] - ta[0], tb[1] - ta[1]))
        if here is not None and abs(here) <= 2 * abs(phi):
            burst = _orbit(planner, poses, ia, ib, here, targets)
            if burst is not None:
                return burst
    stuck = Finish(
        "unreachable",
        f"part {ib + 1} cannot orbit by {phi:.3g} rad with part {ia + 1} held at the anchor: no orbit "
        "step fits that there, or the orbit leaves the travel",
    )
    shift = (anchor[0] - a[0], anchor[1] - a[1])
    if not leg:  # a length leg's orbit is not the last: the plan's turns it back
        phi = _ending_forward(phi, math.hypot(anchor[0] + b[0] - a[0], anchor[1] + b[1] - a[1]), tol)
    if math.hypot(*shift) > 0.5 * tol:
        # B's orbit from where it will be is checked before A goes there (both carried along):
        # a pair 0.9 mm apart went to the anchor, found B in the dead zone and ended 260 µm off
        there = [(p[0] + shift[0], p[1] + shift[1], p[2]) for p in poses]
        ahead = _orbit(planner, there, ia, ib, phi, targets)
        if not isinstance(ahead, AxisBurst):
            return ahead or stuck
        move = _path(planner.translate_burst(poses, ia, anchor, exact=True))
        if not isinstance(move, Finish):  # else A is as close to the anchor as fine steps get it
            return move
    burst = _orbit(planner, poses, ia, ib, phi, targets)
    return stuck if burst is None else burst
