"""τ and w as a pair: the shear strength that goes with a work of adhesion (paper eq. 7).

τ is measured as F/A_r, and A_r depends on w, so a τ is only meaningful with the w
it was fitted with.  The paper's τ = 22.18 ± 3.15 GPa was fitted without adhesion
(w = 0) from its measured forces.  Fitted again with the same forces and the model's
A_r at w, every part on the flat support gives

    τ(w) = τ_paper · A_r(w = 0) / A_r(w),     Δτ(w) = Δτ_paper · A_r(w = 0) / A_r(w),

because the flat support's nominal pressure is the same for every size (so is d, and
A_r(w)/A_r(0) is one number; it is computed for the 300×300×50 part).  τ(w)·A_r(w) on
the flat support is then the measured breakaway force whatever w is; on the grooved
support it scales with the model's grooved/flat ratio at w.  With a surface other than
the embedded one, the paper's τ is taken as fitted with that surface at w = 0, and
``source`` says so: its breakaway force is then not the paper's measured one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.errors import InputError
from feeder.paper import TAU_MEAN_PA, TAU_SPREAD_PA
from feeder.parts import FLAT, Part
from feeder.surface.parameters import DEFAULT_SURFACE, SurfaceParameters

REFERENCE_PART = Part.parse("300x300x50")
FITTED_ADHESION_WORK_J_M2 = 0.016777
"""w that gives the measured grooved/flat ratio 0.74 with GW-MD summits on the embedded
surface (``feeder adhesion fit``; tests/test_adhesion.py checks it against the fit)."""
ADHESION_WORK_REL_BAND = 0.0864
"""Relative half-width of the w band that maps the measured ratio band 0.70–0.78
(0.01530–0.01820 J/m²): the default uncertainty of a given w."""


@dataclass(frozen=True)
class TauPair:
    """τ ± band (Pa) and the work of adhesion w (J/m²) it was fitted with; ``source`` says how."""

    tau_pa: float
    tau_band_pa: float
    adhesion_work_j_m2: float
    source: str


@lru_cache(maxsize=64)
def area_gain(surface: SurfaceParameters) -> float:
    """A_r(w) / A_r(0) of the reference part on the flat support (1 without adhesion)."""
    if surface.adhesion_work_j_m2 == 0:
        return 1.0
    areas = []
    for s in (surface, replace(surface, adhesion_work_j_m2=0.0)):
        gw = GreenwoodWilliamson(s, FLAT.nominal_area_m2(REFERENCE_PART))
        areas.append(float(gw.real_area_m2(gw.separation_m(REFERENCE_PART.weight_n))))
    return areas[0] / areas[1]


def fitted_tau(surface: SurfaceParameters) -> TauPair:
    """The paper's τ re-fitted with the surface's own w (module docstring)."""
    gain = area_gain(surface)
    w = surface.adhesion_work_j_m2
    paper = replace(surface, adhesion_work_j_m2=0.0) == DEFAULT_SURFACE
    return TauPair(
        tau_pa=TAU_MEAN_PA / gain,
        tau_band_pa=TAU_SPREAD_PA / gain,
        adhesion_work_j_m2=w,
        source=f"fitted to the paper's forces with w = {w:g} J/m²"
        if paper
        else f"the paper's τ assumed for this surface{f' (scaled for w = {w:g} J/m² on it)' if w else ''}: "
        "the breakaway force is not the paper's measured one; give --tau from this surface's force curves",
    )


def tau_pair(
    surface: SurfaceParameters,
    tau_pa: float | None = None,
    tau_band_pa: float | None = None,
    tau_adhesion_work_j_m2: float | None = None,
) -> TauPair:
    """The pair to use: τ fitted with the surface's w, or a given τ that states its w.

    A given ``tau_pa`` counts as fitted with ``tau_adhesion_work_j_m2`` (default 0, as the
    paper's); a w that differs from the surface's is refused (:class:`InputError`).
    Without ``tau_band_pa`` a given τ keeps the paper's relative band.
    """
    w = surface.adhesion_work_j_m2
    if tau_pa is None:
        pair = fitted_tau(surface)
        if tau_band_pa is None:
            return pair
        tau_pa, source = pair.tau_pa, pair.source
    else:
        fitted_with = 0.0 if tau_adhesion_work_j_m2 is None else tau_adhesion_work_j_m2
        if not math.isclose(fitted_with, w, rel_tol=1e-9, abs_tol=1e-15):
            raise InputError(
                "--tau",
                f"τ = {tau_pa:g} Pa was fitted with w = {fitted_with:g} J/m² but this contact has "
                f"w = {w:g} J/m²: omit --tau to use the τ fitted with w "
                f"({fitted_tau(surface).tau_pa:.4g} Pa), or give the w it was fitted with "
                "(--tau-adhesion-work)",
            )
        source = f"given (fitted with w = {fitted_with:g} J/m²)"
    if not (math.isfinite(tau_pa) and tau_pa > 0):
        raise InputError("--tau", f"must be a positive number of pascals, got {tau_pa!r}")
    band = tau_pa * TAU_SPREAD_PA / TAU_MEAN_PA if tau_band_pa is None else tau_band_pa
    if not (math.isfinite(band) and 0 <= band < tau_pa):
        raise InputError("--tau-band", f"must be ≥ 0 and below τ, got {band!r}")
    return TauPair(tau_pa, band, w, source)
