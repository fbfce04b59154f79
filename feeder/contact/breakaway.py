"""Breakaway force F = τ·A_r and acceleration a = F/m of a part on its support (paper eq. 7).

The separation d is found from the part's weight (eq. 10), A_r from eq. 11 (with
Maugis–Dugdale summits when w > 0).  τ comes paired with the w it was fitted with
(:mod:`feeder.contact.tau_pair`; paper: 22.18 ± 3.15 GPa at w = 0) and carries its
band into bands on F and a.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.contact.resting_part import rest_part
from feeder.contact.tau_pair import tau_pair
from feeder.errors import InputError
from feeder.paper import GROOVED_AREA_RATIO, GROOVED_FRICTION_RATIO, TAU_MEAN_PA, TAU_SPREAD_PA
from feeder.parts import FLAT, Part, Support
from feeder.surface.parameters import DEFAULT_SURFACE, SILICON_HARDNESS_PA, SurfaceParameters

DEFAULT_TAU_PA = TAU_MEAN_PA
DEFAULT_TAU_BAND_PA = TAU_SPREAD_PA
IDEAL_SHEAR_STRENGTH_PA = 9.6e9
"""Silicon's ideal shear strength, G{111}/2π ≈ 9.6 GPa (range quoted 6–10 GPa)."""
SHEAR_YIELD_PER_HARDNESS = 1.0 / (3.0 * math.sqrt(3.0))
"""Shear yield strength k of a body from its hardness H: H ≈ 3Y (Tabor), k = Y/√3 (von Mises);
no junction is stronger in shear than the softer body's k (Bowden & Tabor)."""
MIN_CONTACTS = 10.0
"""Below this many contacting asperities GW's statistical averaging is unreliable."""
MAX_SAMPLED_CONTACTS = 500.0
"""Above this many contacts the resting placements are not sampled: their draw outgrows the
memory budget (a 5 × 5 mm part, 890 contacts: 2.2 GiB for 2000 placements) and GW's mean field
holds (a 3 × 3 mm part, 320 contacts: the placements' 68 % band is ±3 % of A_r)."""
ELASTIC_PLASTICITY_INDEX = 0.6
PLASTIC_PLASTICITY_INDEX = 1.0


@dataclass(frozen=True)
class ContactResult:
    """Contact state and breakaway figures of one part on one support (SI units)."""

    part: str
    support: str
    mass_kg: float
    weight_n: float
    nominal_area_m2: float
    separation_m: float
    real_area_m2: float
    contacts: float
    tau_pa: float
    tau_band_pa: float
    breakaway_force_n: float
    breakaway_force_band_n: tuple[float, float]
    breakaway_accel_m_s2: float
    breakaway_accel_band_m_s2: tuple[float, float]
    warnings: tuple[str, ...]
    real_area_band_m2: tuple[float, float] | None = None
    """68 % of random placements of the part have A_r in this interval (sampled; None = not sampled)."""
    real_area_sampled_mean_m2: float | None = None
    adhesion_work_j_m2: float = 0.0
    adhesion_n: float = 0.0
    """Adhesive pull of the summits, in and out of contact (N); 0 without adhesion."""
    tau_adhesion_work_j_m2: float = 0.0
    tau_source: str = ""
    plasticity_index: float = 0.0
    attracted_summits: float = 0.0
    """Summits out of contact within the adhesive range, pulling."""
    summit_tabor: float | None = None
    """Maugis' λ of one summit (None without adhesion)."""
    adhesion_parameter: float | None = None
    """Fuller–Tabor's θ = E*σ^{3/2}/(w R^{1/2}) (None without adhesion)."""

    def to_json(self) -> dict[str, Any]:
        """The ``feeder contact --json`` object (unit in every key)."""
        return {
            "part": self.part,
            "support": self.support,
            "mass_kg": self.mass_kg,
            "weight_N": self.weight_n,
            "nominal_area_m2": self.nominal_area_m2,
            "separation_m": self.separation_m,
            "real_area_m2": self.real_area_m2,
            "contacts": self.contacts,
            "tau_pa": self.tau_pa,
            "tau_band_pa": self.tau_band_pa,
            "breakaway_force_N": self.breakaway_force_n,
            "breakaway_force_band_N": list(self.breakaway_force_band_n),
            "breakaway_accel_m_s2": self.breakaway_accel_m_s2,
            "breakaway_accel_band_m_s2": list(self.breakaway_accel_band_m_s2),
            "real_area_band_m2": list(self.real_area_band_m2) if self.real_area_band_m2 else None,
            "real_area_sampled_mean_m2": self.real_area_sampled_mean_m2,
            "adhesion_work_j_m2": self.adhesion_work_j_m2,
            "adhesion_force_N": self.adhesion_n,
            "tau_adhesion_work_j_m2": self.tau_adhesion_work_j_m2,
            "tau_source": self.tau_source,
            "attracted_summits": self.attracted_summits,
            "summit_tabor": self.summit_tabor,
            "adhesion_parameter": self.adhesion_parameter,
            "plasticity_index": self.plasticity_index,
            "warnings": list(self.warnings),
        }


def adhesion_parameter(surface: SurfaceParameters) -> float:
    """Fuller & Tabor's θ = E*·σ^{3/2}/(w·R^{1/2}) (1975): adhesion matters when θ ≲ 10."""
    s = surface
    return s.effective_modulus_pa * s.sigma_m**1.5 / (s.adhesion_work_j_m2 * math.sqrt(s.summit_radius_m))


def _pair_names(surface: SurfaceParameters) -> tuple[str | None, str | None, str | None]:
    """Part, support and softer material of the materials library whose E, ν (and H) the
    surface carries (``--material``/``--support-material`` copy them); None where none matches."""
    from feeder.materials import library

    def named(youngs_pa: float, poisson: float) -> str | None:
        return next(
            (
                m.name
                for m in library().values()
                if m.youngs_modulus_pa == youngs_pa and m.poisson_ratio == poisson
            ),
            None,
        )

    s = surface
    part = named(s.youngs_modulus_pa, s.poisson_ratio)
    support = named(
        s.youngs_modulus_pa if s.support_youngs_modulus_pa is None else s.support_youngs_modulus_pa,
        s.poisson_ratio if s.support_poisson_ratio is None else s.support_poisson_ratio,
    )
    by_hardness = {m.name for m in library().values() if m.hardness_pa == surface.hardness_pa}
    softer = next((name for name in (part, support) if name in by_hardness), None)
    return part, support, softer


def _shear_strength_warning(surface: SurfaceParameters, tau_pa: float, hint: str) -> str | None:
    """τ above what the softer body can carry in shear: silicon's ideal shear strength for
    silicon (the default hardness), else the softer body's shear yield strength H/(3√3)."""
    w = surface.adhesion_work_j_m2
    if surface.hardness_pa == SILICON_HARDNESS_PA:
        if tau_pa <= IDEAL_SHEAR_STRENGTH_PA:
            return None
        reason = (
            ": the model neglects adhesion, so A_r is underestimated and τ absorbs the difference" + hint
            if not w
            else f", even with adhesion w = {w:g} J/m²"
        )
        return (
            f"τ = {tau_pa / 1e9:.2f} GPa exceeds silicon's ideal shear strength (≈ 6–10 GPa, "
            f"G{{111}}/2π ≈ 9.6 GPa){reason}"
        )
    limit = SHEAR_YIELD_PER_HARDNESS * surface.hardness_pa
    if tau_pa <= limit:
        return None
    part, support, softer = _pair_names(surface)
    body = f"{softer}'s" if softer else "the softer body's"
    pair = f"{part} on {support}" if part and support else "this pair"
    return (
        f"τ = {tau_pa / 1e9:.3g} GPa is {tau_pa / limit:.3g}× {body} shear yield strength "
        f"(k ≈ H/(3√3) = {limit / 1e9:.3g} GPa, H = {surface.hardness_pa / 1e9:.3g} GPa), which no "
        f"junction exceeds: this τ does not fit {pair} (the paper's τ is silicon on silicon's; give "
        "--tau measured for this pair)"
        + ("" if w else "; the model also neglects adhesion (--adhesion-work), underestimating A_r")
    )


def _warnings(
    part: Part,
    support: Support,
    surface: SurfaceParameters,
    contacts: float,
    tau_pa: float,
    real_area_m2: float,
    adhesion_n: float,
) -> list[str]:
    out = []
    w = surface.adhesion_work_j_m2
    hint = "" if w else " (--adhesion-work adds Maugis–Dugdale adhesion; silicon in air: w ≈ 0.02–0.1 J/m²)"
    psi = surface.plasticity_index
    if psi > PLASTIC_PLASTICITY_INDEX:
        out.append(
            f"plasticity index ψ = {psi:.2f} > {PLASTIC_PLASTICITY_INDEX:g}: most summits yield; the "
            "elastic (Hertz/GW) model no longer holds"
        )
    elif psi > ELASTIC_PLASTICITY_INDEX:
        out.append(
            f"plasticity index ψ = {psi:.2f} > {ELASTIC_PLASTICITY_INDEX:g} (E*/H·√(σ/R), H = "
            f"{surface.hardness_pa / 1e9:.3g} GPa): part of the summits yield; the elastic model is "
            "borderline (elastic below 0.6, mostly plastic above 1)"
        )
    if contacts < MIN_CONTACTS:
        out.append(
            f"only {contacts:.2g} asperities in contact (< {MIN_CONTACTS:g}): Greenwood–Williamson "
            "statistics are unreliable at this size"
        )
    shear = _shear_strength_warning(surface, tau_pa, hint)
    if shear is not None:
        out.append(shear)
    if w and adhesion_n > part.weight_n:
        out.append(
            f"adhesion ({adhesion_n:.3g} N) exceeds the part's weight ({part.weight_n:.3g} N): the "
            "contact is adhesion-dominated and A_r scales with the nominal area, not the weight"
        )
    if support.kind == "grooved":
        flat = GreenwoodWilliamson(surface, FLAT.nominal_area_m2(part))
        ratio = real_area_m2 / float(flat.real_area_m2(flat.separation_m(part.weight_n)))
        if w:
            out.append(
                f"grooved/flat real-area ratio is {ratio:.3f} with Maugis–Dugdale adhesion "
                f"w = {w:g} J/m² (measured friction ratio {GROOVED_FRICTION_RATIO}; feeder adhesion "
                "fit finds the w that gives it)"
            )
        else:
            out.append(
                f"grooved/flat real-area ratio is {ratio:.3f} in this model, not the paper's "
                f"{GROOVED_AREA_RATIO}: halving the summits at the same load barely changes A_r in "
                "GW/Hertz; the measured friction ratio "
                f"{GROOVED_FRICTION_RATIO} needs adhesion, whose load scales with nominal area" + hint
            )
    return out


def contact(
    part: Part,
    support: Support = FLAT,
    surface: SurfaceParameters = DEFAULT_SURFACE,
    tau_pa: float | None = None,
    tau_band_pa: float | None = None,
    placements: int = 0,
    *,
    tau_adhesion_work_j_m2: float | None = None,
) -> ContactResult:
    """Separation, real area and breakaway force/acceleration of ``part`` resting on ``support``.

    τ and w are a pair (:func:`feeder.contact.tau_pair.tau_pair`): without ``tau_pa``
    the τ fitted with the surface's w is used; a given ``tau_pa`` is fitted with
    ``tau_adhesion_work_j_m2`` (default 0) and refused if that is not the surface's w.
    ``placements`` > 0 also samples that many random placements of the rigid part,
    each at rest on ≥ 3 summits with its tilt (:mod:`feeder.contact.resting_part`,
    ~0.3 s for 2000), for the A_r band (without adhesion only: Hertzian summits; not
    beyond :data:`MAX_SAMPLED_CONTACTS` contacts, where a warning says so).
    """
    pair = tau_pair(surface, tau_pa, tau_band_pa, tau_adhesion_work_j_m2)
    tau_pa, tau_band_pa = pair.tau_pa, pair.tau_band_pa
    gw = GreenwoodWilliamson(surface, support.nominal_area_m2(part))
    try:
        separation = float(gw.separation_m(part.weight_n))
    except InputError as err:
        raise InputError("--part", f"the surface cannot carry this part: {err.message}") from None
    area = float(gw.real_area_m2(separation))
    contacts = float(gw.contacts(separation))
    adhesion = float(gw.adhesion_n(separation))
    force = tau_pa * area
    band = ((tau_pa - tau_band_pa) * area, (tau_pa + tau_band_pa) * area)
    mass = part.mass_kg
    warnings = _warnings(part, support, surface, contacts, tau_pa, area, adhesion)
    band_m2: tuple[float, float] | None = None
    sampled_mean: float | None = None
    if placements > 0 and contacts > MAX_SAMPLED_CONTACTS:
        warnings.append(
            f"no A_r band from resting placements: {contacts:.0f} contacts under this part, beyond the "
            f"{MAX_SAMPLED_CONTACTS:.0f} the sampler is for; GW's mean field holds"
        )
    elif placements > 0 and not surface.adhesion_work_j_m2:  # the sampling is Hertz-only
        try:
            sampled = rest_part(surface, part, support, placements=placements)
        except InputError as err:
            raise InputError(
                "--placements", f"{err.message} (this part, {placements} placements; 0 skips the sampling)"
            ) from None
        except ArithmeticError as err:  # GW's mean field stands; only the placements' band is missing
            sampled = None
            warnings.append(
                f"no A_r band from resting placements: this part's rest on the summits was not found ({err})"
            )
        if sampled is not None:
            band_m2, sampled_mean = sampled.band_m2(), float(np.mean(sampled.real_area_m2))
            if contacts < MIN_CONTACTS:
                warnings.append(
                    f"resting tilted on its highest summits (≥ 3, centre of mass inside), this part's A_r is "
                    f"{band_m2[0]:.3g}–{band_m2[1]:.3g} m² (68 % of {placements} placements, mean "
                    f"{sampled_mean:.3g}); GW's mean-field value {area:.3g} m² assumes fractional asperities"
                )
    return ContactResult(
        part=part.label,
        support=support.kind,
        mass_kg=mass,
        weight_n=part.weight_n,
        nominal_area_m2=gw.nominal_area_m2,
        separation_m=separation,
        real_area_m2=area,
        contacts=contacts,
        tau_pa=tau_pa,
        tau_band_pa=tau_band_pa,
        breakaway_force_n=force,
        breakaway_force_band_n=band,
        breakaway_accel_m_s2=force / mass,
        breakaway_accel_band_m_s2=(band[0] / mass, band[1] / mass),
        warnings=tuple(warnings),
        real_area_band_m2=band_m2,
        real_area_sampled_mean_m2=sampled_mean,
        adhesion_work_j_m2=surface.adhesion_work_j_m2,
        adhesion_n=adhesion,
        tau_adhesion_work_j_m2=pair.adhesion_work_j_m2,
        tau_source=pair.source,
        plasticity_index=surface.plasticity_index,
        attracted_summits=float(gw.attracted(separation)),
        summit_tabor=gw.summit_law.sphere.tabor if gw.summit_law else None,
        adhesion_parameter=adhesion_parameter(surface) if surface.adhesion_work_j_m2 else None,
    )
