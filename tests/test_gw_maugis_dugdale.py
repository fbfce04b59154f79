"""GW with Maugis–Dugdale summits (attraction out of contact included): the w → 0 limit is
GW/Hertz, and load and area match a slow pointwise quad/brentq reference."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq, minimize_scalar
from test_greenwood_williamson import Reference

from feeder.contact.adhesion_sphere import SphereContact
from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.surface.parameters import DEFAULT_SURFACE, SurfaceParameters

WEIGHT_300 = 1.0285e-7


def _md_state(abar: float, lam: float) -> tuple[float, float]:
    """(P̄, δ̄) of Maugis' contact branch by brentq on t = √(m²−1) (scalar, no shared code)."""

    def f(t: float) -> float:
        m = math.sqrt(1 + t * t)
        return (0.5 * lam * abar**2 * (t + (m * m - 2) * math.atan(t))
                + 4 / 3 * lam**2 * abar * (t * math.atan(t) - t * t / (m + 1)) - 1)  # fmt: skip

    hi = 1.0
    while f(hi) < 0:
        hi *= 4
    t = brentq(f, 0.0, hi, xtol=1e-300, rtol=1e-15)
    m = math.sqrt(1 + t * t)
    return abar**3 - lam * abar**2 * (t + m * m * math.atan(t)), abar**2 - 4 / 3 * lam * abar * t


class MaugisDugdaleReference(Reference):
    """ΔP, ΔA of GW-MD by quad over z, each summit's MD state solved pointwise by brentq."""

    def __init__(self, s: SurfaceParameters, area: float) -> None:
        super().__init__(s, area)
        self.sphere = SphereContact.from_range(
            s.summit_radius_m, s.effective_modulus_pa, s.adhesion_work_j_m2, s.adhesion_range_m
        )
        lam = self.lam = self.sphere.tabor
        self.b, self.h0 = 8 * lam / (3 * math.pi), 2 / (math.pi * lam)
        qa, qb = math.pi * lam / 4, 4 / 3 * lam**2 * (math.pi / 2 - 1)
        c_edge = (-qb + math.sqrt(qb * qb + 4 * qa)) / (2 * qa)
        self.edge = max(-4 / 3 * lam * c_edge, -self.h0)
        lowest = minimize_scalar(lambda a: _md_state(a, lam)[1], bounds=(1e-6, 20), method="bounded")
        self.a_low = float(lowest.x) if lowest.fun < -4 / 3 * lam * c_edge - 1e-9 else 1e-9

    def summit(self, s_bar: float) -> tuple[float, float]:
        """(P̄ − Hertz, ā² − Hertz) of one summit at approach δ̄ (approach history)."""
        if s_bar < -self.h0:
            return 0.0, 0.0
        if s_bar < self.edge:
            c = self.b + math.sqrt(self.b**2 + 2 * (self.h0 + s_bar))
            return -math.pi * self.lam / 2 * c * c, 0.0
        hi = math.sqrt(max(s_bar, 0.0)) + 4 * self.lam + 4
        a = brentq(lambda x: _md_state(x, self.lam)[1] - s_bar, self.a_low, hi, xtol=1e-15, rtol=1e-14)
        hertz = max(s_bar, 0.0)
        return _md_state(a, self.lam)[0] - hertz**1.5, a * a - hertz

    def corrections(self, d: float, parts: tuple[int, ...] = (0, 1)) -> tuple[float, ...]:
        unit = self.sphere.approach_unit_m
        lo, top = d - self.h0 * unit, self.s.z_max
        breaks = [d + self.edge * unit, d]
        out = []
        for i in parts:
            f = lambda z, i=i: self.summit((z - d) / unit)[i] * self.phi(z)  # noqa: E731
            out.append(quad(f, lo, top, points=breaks, epsabs=0, epsrel=1e-10, limit=400)[0])
        scales = (self.n * self.sphere.load_unit_n, self.n * math.pi * self.sphere.radius_unit_m**2)
        return tuple(scales[i] * value for i, value in zip(parts, out, strict=True))

    def net_load(self, d: float) -> float:
        return self.load(d) + self.corrections(d, (0,))[0]


def test_zero_adhesion_limit_is_gw_to_1e_9() -> None:
    plain = GreenwoodWilliamson(DEFAULT_SURFACE, 9e-8)
    d_plain = float(plain.separation_m(WEIGHT_300))
    for w in (1e-9, 1e-12):
        tiny = GreenwoodWilliamson(replace(DEFAULT_SURFACE, adhesion_work_j_m2=w), 9e-8)
        assert tiny.summit_law is not None  # the MD path runs
        d = float(tiny.separation_m(WEIGHT_300))
        assert d == pytest.approx(d_plain, rel=1e-9)
        assert float(tiny.real_area_m2(d)) == pytest.approx(float(plain.real_area_m2(d_plain)), rel=1e-9)
        assert float(tiny.load_n(d_plain)) == pytest.approx(WEIGHT_300, rel=1e-9)
    exact = GreenwoodWilliamson(replace(DEFAULT_SURFACE, adhesion_work_j_m2=0.0), 9e-8)
    assert exact.summit_law is None and float(exact.separation_m(WEIGHT_300)) == d_plain


@pytest.mark.parametrize(("w", "range_m"), [(0.1, None), (3.0, 0.2e-9)])  # λ = 0.16 and 2.2 (jump-in)
def test_corrections_match_pointwise_quad_reference(w: float, range_m: float | None) -> None:
    surface = replace(DEFAULT_SURFACE, adhesion_work_j_m2=w)
    if range_m is not None:
        surface = replace(surface, adhesion_range_m=range_m)
    gw, ref = GreenwoodWilliamson(surface, 9e-8), MaugisDugdaleReference(surface, 9e-8)
    for k in (-1.0, 3.0):
        d = surface.mean_summit_height_m + k * surface.sigma_m
        h = np.array([(d - surface.mean_summit_height_m) / surface.sigma_m])
        load, area, _ = gw._corrections(h)
        ref_load, ref_area = ref.corrections(d)
        assert float(load[0]) == pytest.approx(ref_load, rel=1e-8)
        assert float(area[0]) == pytest.approx(ref_area, rel=1e-8)


def test_separation_is_the_largest_root_and_round_trips() -> None:
    surface = replace(DEFAULT_SURFACE, adhesion_work_j_m2=0.1)
    gw = GreenwoodWilliamson(surface, 9e-8)
    loads = np.geomspace(1e-9, 1e-4, 7)
    d = gw.separation_m(loads)
    assert np.all(np.diff(d) < 0)
    np.testing.assert_allclose(gw.load_n(d), loads, rtol=1e-8)
    above = d[:, None] + np.linspace(1e-12, 20 * surface.sigma_m, 400)[None, :]
    assert np.all(gw.load_n(above) < loads[:, None])  # nothing at larger d carries the load
    # adhesion only ever adds compression and area
    plain = GreenwoodWilliamson(DEFAULT_SURFACE, 9e-8)
    assert np.all(d < plain.separation_m(loads))
    assert np.all(gw.real_area_m2(d) > plain.real_area_m2(d))


def test_attracted_summits_and_contacts() -> None:
    gw = GreenwoodWilliamson(replace(DEFAULT_SURFACE, adhesion_work_j_m2=0.1), 9e-8)
    d = float(gw.separation_m(WEIGHT_300))
    assert float(gw.attracted(d)) > 0
    # contacts include summits pulled into contact below δ = 0
    plain = GreenwoodWilliamson(DEFAULT_SURFACE, 9e-8)
    assert float(gw.contacts(d)) > float(plain.contacts(d))
