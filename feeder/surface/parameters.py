"""Parameters of the equivalent rough surface (paper eqs. 1–3) and their TOML file.

File format (also written by ``feeder surface --out``)::

    [surface]
    sigma_m = 0.482e-9
    summit_radius_m = 55.0e-9
    summit_density_per_m2 = 124.1e12
    mean_summit_height_m = 32.227e-9
    # z_max_m = ...   (optional; default mean + 10 sigma)
    [material]          # applies to both bodies
    youngs_modulus_pa = 169e9
    poisson_ratio = 0.28
    # adhesion_work_j_m2 = 0.1   (optional; Maugis–Dugdale adhesion per summit, default 0)
    # adhesion_range_m = 0.2913e-9   (optional; Dugdale range h0 = w/sigma0, default 0.971 z0)
    # hardness_pa = 12e9   (optional; for the plasticity index, default silicon)
    # support_youngs_modulus_pa = 345e9, support_poisson_ratio = 0.29
    #     (optional; the support's own material, default the same as the part's)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from feeder.errors import InputError
from feeder.files import read_toml, toml_number, write_text

Z_MAX_SIGMAS = 10.0
SILICON_HARDNESS_PA = 12e9
"""Silicon's indentation hardness, 11–13 GPa (nanoindentation of (100) Si)."""
DEFAULT_ADHESION_RANGE_M = 0.971 * 0.3e-9
"""Dugdale range h₀ = 0.971·z₀ (z₀ = 0.3 nm): σ₀h₀ = w with σ₀ = 1.03·w/z₀ (Maugis 1992)."""
MAX_HEIGHT_M = 1e-3
"""σ, |μ| and z_max above 1 mm are no surface roughness (AFM scans: 0.1–100 nm): a unit slip."""
MIN_SUMMIT_RADIUS_M = 1e-12
"""A summit radius below 1 pm (a hundredth of an atom) is no asperity: a unit slip."""
MAX_SUMMIT_RADIUS_M = 1.0
"""A mean summit radius beyond 1 m is no asperity either: a few nearly flat summits (quantised
heights) dominate the mean (integer-valued noise gave 36.5 km, and a breakaway of 2.3e7 g)."""
MAX_SUMMIT_DENSITY_PER_M2 = 1e20
"""More than one summit per (0.1 nm)² is denser than the atoms: a unit slip."""
YOUNGS_MODULUS_RANGE_PA = (1e6, 1e13)
"""Young's moduli of solids in contact: from soft elastomers (≈ 1 MPa) to ten times diamond's
(1.05 TPa). The library (docs/materials.md) spans 3 GPa (PMMA) to 345 GPa (sapphire), three
decades inside; a bare ``169`` (GPa meant, 169 Pa read) is far below and refused."""
ADHESION_WORK_RANGE_J_M2 = (1e-6, 10.0)
"""A work of adhesion w is 0 (the paper's model) or 1 µJ/m²–10 J/m²: solids in air give
0.01–0.1 J/m², clean ones in vacuum a few J/m² (twice the surface energy); ``--adhesion-work``
and a surface file's ``adhesion_work_j_m2`` share this range."""
ADHESION_WORK_HELP = f"0 or {ADHESION_WORK_RANGE_J_M2[0]:g}–{ADHESION_WORK_RANGE_J_M2[1]:g}"
"""The range of w as the options' help and errors say it (J/m²)."""


@dataclass(frozen=True)
class SurfaceParameters:
    """Equivalent rough surface against a smooth plane (SI units).

    sigma_m: std of summit heights σ (eq. 3); summit_radius_m: R (eq. 1);
    summit_density_per_m2: η; mean_summit_height_m: μ; z_max_m: highest summit
    (default μ + 10σ); youngs_modulus_pa, poisson_ratio: both bodies;
    adhesion_work_j_m2: work of adhesion w of the interface (J/m²; 0 = the
    paper's adhesion-free model), used as Maugis–Dugdale adhesion per summit
    (:mod:`feeder.contact.gw_maugis_dugdale`); adhesion_range_m: its Dugdale range
    h₀ = w/σ₀ (default 0.971·z₀, z₀ = 0.3 nm, Maugis' match to Lennard-Jones);
    hardness_pa: indentation hardness H of the softer body (plasticity index);
    support_youngs_modulus_pa, support_poisson_ratio: the support's material when it
    differs from the part's (None = the same).
    """

    sigma_m: float
    summit_radius_m: float
    summit_density_per_m2: float
    mean_summit_height_m: float
    youngs_modulus_pa: float = 169e9
    poisson_ratio: float = 0.28
    z_max_m: float | None = None
    adhesion_work_j_m2: float = 0.0
    adhesion_range_m: float = DEFAULT_ADHESION_RANGE_M
    hardness_pa: float = SILICON_HARDNESS_PA
    support_youngs_modulus_pa: float | None = None
    support_poisson_ratio: float | None = None

    def __post_init__(self) -> None:
        positive = ("sigma_m", "summit_radius_m", "summit_density_per_m2", "youngs_modulus_pa", "hardness_pa")
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(name, f"must be a positive number, got {value!r}")
        if not math.isfinite(self.mean_summit_height_m):
            raise InputError("mean_summit_height_m", "must be a finite number")
        if not (-1.0 < self.poisson_ratio < 0.5):
            raise InputError("poisson_ratio", f"must lie in (-1, 0.5), got {self.poisson_ratio!r}")
        if not (math.isfinite(self.adhesion_work_j_m2) and self.adhesion_work_j_m2 >= 0):
            raise InputError("adhesion_work_j_m2", f"must be ≥ 0, got {self.adhesion_work_j_m2!r}")
        if not (math.isfinite(self.adhesion_range_m) and self.adhesion_range_m > 0):
            raise InputError("adhesion_range_m", f"must be a positive length, got {self.adhesion_range_m!r}")
        if self.support_youngs_modulus_pa is not None and not (
            math.isfinite(self.support_youngs_modulus_pa) and self.support_youngs_modulus_pa > 0
        ):
            raise InputError("support_youngs_modulus_pa", "must be a positive number")
        if self.support_poisson_ratio is not None and not (-1.0 < self.support_poisson_ratio < 0.5):
            raise InputError(
                "support_poisson_ratio", f"must lie in (-1, 0.5), got {self.support_poisson_ratio!r}"
            )
        if self.z_max_m is not None and not (
            math.isfinite(self.z_max_m) and self.z_max_m > self.mean_summit_height_m
        ):
            raise InputError("z_max_m", "must be a finite height above mean_summit_height_m")

    @property
    def z_max(self) -> float:
        """Highest summit height (m)."""
        if self.z_max_m is not None:
            return self.z_max_m
        return self.mean_summit_height_m + Z_MAX_SIGMAS * self.sigma_m

    @property
    def plasticity_index(self) -> float:
        """ψ = (E*/H)·√(σ/R) (Greenwood & Williamson 1966): < 0.6 elastic, > 1 mostly plastic."""
        return self.effective_modulus_pa / self.hardness_pa * math.sqrt(self.sigma_m / self.summit_radius_m)

    @property
    def effective_modulus_pa(self) -> float:
        """E*: 1/E* = (1 − ν₁²)/E₁ + (1 − ν₂²)/E₂; E / (2(1 − ν²)) for one material."""
        e2 = (
            self.youngs_modulus_pa
            if self.support_youngs_modulus_pa is None
            else self.support_youngs_modulus_pa
        )
        nu2 = self.poisson_ratio if self.support_poisson_ratio is None else self.support_poisson_ratio
        return 1.0 / ((1.0 - self.poisson_ratio**2) / self.youngs_modulus_pa + (1.0 - nu2**2) / e2)

    def to_toml(self) -> str:
        lines = [
            "[surface]",
            f"sigma_m = {self.sigma_m!r}",
            f"summit_radius_m = {self.summit_radius_m!r}",
            f"summit_density_per_m2 = {self.summit_density_per_m2!r}",
            f"mean_summit_height_m = {self.mean_summit_height_m!r}",
        ]
        if self.z_max_m is not None:
            lines.append(f"z_max_m = {self.z_max_m!r}")
        lines += [
            "",
            "[material]",
            f"youngs_modulus_pa = {self.youngs_modulus_pa!r}",
            f"poisson_ratio = {self.poisson_ratio!r}",
        ]
        if self.adhesion_work_j_m2:
            lines.append(f"adhesion_work_j_m2 = {self.adhesion_work_j_m2!r}")
        if self.adhesion_range_m != DEFAULT_ADHESION_RANGE_M:
            lines.append(f"adhesion_range_m = {self.adhesion_range_m!r}")
        if self.hardness_pa != SILICON_HARDNESS_PA:
            lines.append(f"hardness_pa = {self.hardness_pa!r}")
        if self.support_youngs_modulus_pa is not None:
            lines.append(f"support_youngs_modulus_pa = {self.support_youngs_modulus_pa!r}")
        if self.support_poisson_ratio is not None:
            lines.append(f"support_poisson_ratio = {self.support_poisson_ratio!r}")
        lines.append("")
        return "\n".join(lines)

    def write_toml(self, path: Path) -> None:
        """Write atomically (temporary file, then rename): nothing half-written."""
        write_text(path, self.to_toml())


DEFAULT_SURFACE = SurfaceParameters(
    sigma_m=0.482e-9,
    summit_radius_m=55.0e-9,
    summit_density_per_m2=124.1e12,
    mean_summit_height_m=32.227e-9,
)
"""Embedded default (DESIGN §2): reproduces the paper's flat-support Table III."""

_REQUIRED_KEYS = ("sigma_m", "summit_radius_m", "summit_density_per_m2", "mean_summit_height_m")
_SURFACE_KEYS = (*_REQUIRED_KEYS, "z_max_m")
_MATERIAL_KEYS = (
    "youngs_modulus_pa",
    "poisson_ratio",
    "adhesion_work_j_m2",
    "adhesion_range_m",
    "hardness_pa",
    "support_youngs_modulus_pa",
    "support_poisson_ratio",
)


def adhesion_work_problem(value: float) -> str | None:
    """Why ``value`` (J/m²) is no work of adhesion (:data:`ADHESION_WORK_RANGE_J_M2`), else None."""
    low, high = ADHESION_WORK_RANGE_J_M2
    if value == 0 or low <= value <= high:  # NaN fails both
        return None
    return f"must be {ADHESION_WORK_HELP} J/m², got {value!r}"


def load_surface(path: Path) -> SurfaceParameters:
    """Read a surface TOML file; every problem is an :class:`InputError` naming file and field."""
    data = read_toml(path)
    surface = data.get("surface")
    if not isinstance(surface, dict):
        raise InputError(str(path), "missing [surface] table")
    material = data.get("material", {})
    if not isinstance(material, dict):
        raise InputError(str(path), "[material] must be a table")
    values: dict[str, float] = {}
    tables = ((surface, _SURFACE_KEYS, "surface"), (material, _MATERIAL_KEYS, "material"))
    for table, allowed, name in tables:
        for key, value in table.items():
            if key not in allowed:
                raise InputError(f"{path}: [{name}].{key}", "unknown field")
            values[key] = toml_number(f"{path}: [{name}].{key}", value)
    for key in _REQUIRED_KEYS:
        if key not in values:
            raise InputError(f"{path}: [surface].{key}", "missing")
    try:
        parameters = SurfaceParameters(**values)
    except InputError as err:
        raise InputError(f"{path}: {err.field}", err.message) from None
    problem = implausible(parameters)
    if problem is not None:
        key, message = problem
        where = "material" if key in _MATERIAL_KEYS else "surface"
        raise InputError(f"{path}: [{where}].{key}", message)
    return parameters


def implausible(surface: SurfaceParameters) -> tuple[str, str] | None:
    """The first physically impossible summit statistic or material constant of ``surface`` as
    (field, why), else None.

    Positive and finite is not enough: heights read in the wrong unit (metres for nm) give
    σ ≈ 1 m and R ≈ 1e-17 m, which the contact model turns into a separation of 1e10 nm.
    Bounds: σ, |μ|, z_max ≤ 1 mm; 1 pm ≤ R ≤ 1 m; η ≤ 1e20 m⁻² (one summit per (0.1 nm)²);
    Young's moduli 1 MPa–10 TPa (:data:`YOUNGS_MODULUS_RANGE_PA`; a modulus in GPa read as Pa
    made the part "too heavy for the surface"); w 0 or 1 µJ/m²–10 J/m²
    (:data:`ADHESION_WORK_RANGE_J_M2`; 1e3 J/m² gave a negative load capacity).
    """
    hint = ": not a surface's summit statistics (heights in the wrong unit?)"
    heights = [("sigma_m", surface.sigma_m), ("mean_summit_height_m", surface.mean_summit_height_m)]
    if surface.z_max_m is not None:
        heights.append(("z_max_m", surface.z_max_m))
    for key, value in heights:
        if abs(value) > MAX_HEIGHT_M:
            return key, f"{value:.4g} m is beyond {MAX_HEIGHT_M * 1e3:g} mm{hint}"
    if surface.summit_radius_m < MIN_SUMMIT_RADIUS_M:
        radius = surface.summit_radius_m
        return "summit_radius_m", f"{radius:.4g} m is below {MIN_SUMMIT_RADIUS_M * 1e12:g} pm{hint}"
    if surface.summit_radius_m > MAX_SUMMIT_RADIUS_M:
        radius = surface.summit_radius_m
        return "summit_radius_m", (f"{radius:.4g} m is beyond {MAX_SUMMIT_RADIUS_M:g} m: not an asperity's "
                                   "(nearly flat summits, quantised heights?)")  # fmt: skip
    if surface.summit_density_per_m2 > MAX_SUMMIT_DENSITY_PER_M2:
        density = surface.summit_density_per_m2
        return "summit_density_per_m2", f"{density:.4g} m⁻² is above {MAX_SUMMIT_DENSITY_PER_M2:g} m⁻²{hint}"
    low, high = YOUNGS_MODULUS_RANGE_PA
    for key, modulus in (("youngs_modulus_pa", surface.youngs_modulus_pa),
                         ("support_youngs_modulus_pa", surface.support_youngs_modulus_pa)):  # fmt: skip
        if modulus is not None and not low <= modulus <= high:
            return key, (f"{modulus:.4g} Pa is outside {low:g}–{high:g} Pa, no solid's Young's modulus "
                         "(in pascals: silicon is 169e9)")  # fmt: skip
    problem = adhesion_work_problem(surface.adhesion_work_j_m2)
    if problem is not None:
        return "adhesion_work_j_m2", problem
    return None
