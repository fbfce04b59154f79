"""GW held against a full elastic solution on the measured topography (DESIGN §11).

ContactMechanics' FFT boundary-element solver (Pastewka, Sanner et al.;
``make_system(substrate="periodic")``, constrained conjugate gradients,
``minimize_proxy``) presses the plane-removed height map, taken as one period of a
periodic surface, onto a rigid flat with the reduced modulus E* at the nominal
pressure p: total force p·A over the scan area A.  Its real-area fraction
A_r/A = (pixels in contact)·(pixel area)/A is set beside GW's for the scan's own
summit statistics (eqs. 4–11 at the same p).

The BEM area is only as good as its resolution: a contact patch narrower than a
pixel counts as one whole pixel.  At a part's nominal pressure (≈ 1 Pa for 50 µm of
silicon) a scan of a few µm carries a few 1e-11 N, the highest pixel carries it
alone, and the BEM "area" is one pixel area, an upper bound many orders above the
true one.  So the comparison is also made over a sweep of higher pressures, and
each point says how many pixels are in contact (``resolved`` when at least
:data:`RESOLVED_PIXELS`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from feeder.contact.greenwood_williamson import GreenwoodWilliamson
from feeder.errors import InputError
from feeder.surface.parameters import SurfaceParameters

log = logging.getLogger(__name__)

RESOLVED_PIXELS = 30
"""Fewer contact pixels than this: the BEM area is pixel-limited (patches not resolved)."""
PRESSURE_SWEEP = (1.0, 1e6, 1e7, 1e8)
"""Multiples of the nominal pressure at which the comparison is made."""
_PENETRATION_FRACTION = 1e-4
"""Penetration tolerance of the solver as a fraction of Sq (a fixed length fails on smooth maps)."""
_MAX_ITERATIONS = 3000


@dataclass(frozen=True)
class BemPoint:
    """One pressure: BEM and GW real-area fractions and the BEM's contact pixels (SI units)."""

    pressure_pa: float
    bem_real_area_fraction: float
    gw_real_area_fraction: float
    contact_pixels: int
    gw_contacts: float
    """GW's expected number of summits in contact over the scan area."""

    @property
    def ratio(self) -> float:
        """BEM / GW real area."""
        return self.bem_real_area_fraction / self.gw_real_area_fraction

    @property
    def resolved(self) -> bool:
        return self.contact_pixels >= RESOLVED_PIXELS

    def to_json(self) -> dict[str, Any]:
        return {
            "pressure_pa": self.pressure_pa,
            "bem_real_area_fraction": self.bem_real_area_fraction,
            "gw_real_area_fraction": self.gw_real_area_fraction,
            "bem_gw_ratio": self.ratio,
            "bem_contact_pixels": self.contact_pixels,
            "gw_contacts_on_scan": self.gw_contacts,
            "bem_resolved": self.resolved,
        }


def bem_contact_fraction(
    heights_m: np.ndarray, pixel_size_m: tuple[float, float], effective_modulus_pa: float, pressure_pa: float
) -> tuple[float, int]:
    """Real-area fraction and contact pixels of the periodic height map pressed at ``pressure_pa``.

    Raises InputError (``--bem``) without ContactMechanics, ArithmeticError if the solver fails.
    """
    try:
        from ContactMechanics import make_system
        from ContactMechanics.Tools.Logger import quiet
        from SurfaceTopography import Topography
    except ImportError:
        raise InputError("--bem", "needs ContactMechanics: pip install 'feeder[bem]'") from None
    n0, n1 = heights_m.shape
    sizes = (n0 * pixel_size_m[0], n1 * pixel_size_m[1])
    topography = Topography(np.asarray(heights_m, dtype=float), sizes, periodic=True)
    system = make_system(substrate="periodic", surface=topography, young=effective_modulus_pa)
    force = pressure_pa * sizes[0] * sizes[1]
    pentol = _PENETRATION_FRACTION * float(np.std(heights_m))
    result = system.minimize_proxy(external_force=force, pentol=pentol, maxiter=_MAX_ITERATIONS, logger=quiet)
    if not result.success:
        raise ArithmeticError(f"BEM solver did not converge at {pressure_pa:g} Pa: {result.message}")
    pixels = int(np.count_nonzero(system.contact_zone))
    return pixels / (n0 * n1), pixels


def compare_with_gw(
    heights_m: np.ndarray,
    pixel_size_m: tuple[float, float],
    surface: SurfaceParameters,
    nominal_pressure_pa: float,
    multiples: tuple[float, ...] = PRESSURE_SWEEP,
) -> tuple[list[BemPoint], list[str]]:
    """BEM vs GW (``surface``: the scan's own statistics) at ``nominal_pressure_pa`` × each multiple,
    and notes on where the sweep stopped (a pressure beyond GW's range, or one the solver does not
    converge at: only the nominal pressure must succeed)."""
    n0, n1 = heights_m.shape
    area = n0 * pixel_size_m[0] * n1 * pixel_size_m[1]
    gw = GreenwoodWilliamson(surface, area)
    points: list[BemPoint] = []
    notes: list[str] = []
    for multiple in multiples:
        pressure = nominal_pressure_pa * multiple
        load = pressure * area
        if load > gw.max_load_n:
            notes.append(f"BEM sweep stops at {pressure:.3g} Pa: beyond GW's range")
            break
        try:
            fraction, pixels = bem_contact_fraction(
                heights_m, pixel_size_m, surface.effective_modulus_pa, pressure
            )
        except ArithmeticError as err:
            if not points:
                raise
            notes.append(f"BEM sweep stops: {err}")
            break
        d = gw.separation_m(load)
        points.append(
            BemPoint(
                pressure_pa=pressure,
                bem_real_area_fraction=fraction,
                gw_real_area_fraction=float(gw.real_area_m2(d)) / area,
                contact_pixels=pixels,
                gw_contacts=float(gw.contacts(d)),
            )
        )
    for note in notes:
        log.info(note)
    return points, notes


def reading(points: list[BemPoint]) -> list[str]:
    """What the sweep says, in words: where the BEM is pixel-limited, where GW and BEM agree."""
    out = []
    nominal = points[0]
    if not nominal.resolved:
        out.append(
            f"at the nominal pressure {nominal.pressure_pa:.3g} Pa the BEM contact is "
            f"{nominal.contact_pixels} pixel(s): its area is one pixel's, an upper bound, and GW expects "
            f"{nominal.gw_contacts:.2g} summits in contact on the whole scan; the ratio says nothing there"
        )
    resolved = [p for p in points if p.resolved]
    if resolved:
        best = resolved[0]
        out.append(
            f"first resolved point: {best.pressure_pa:.3g} Pa, {best.contact_pixels} contact pixels, "
            f"BEM/GW = {best.ratio:.3g}"
        )
    else:
        out.append("no pressure of the sweep resolves the BEM contact: GW cannot be checked on this scan")
    return out
