"""The materials library: elastic constants, hardness, density and adhesion, sources cited.

One TOML file per material in this package (read with :mod:`importlib.resources`):
``name``, ``aliases``, ``youngs_modulus_pa``, ``poisson_ratio``, ``hardness_pa``,
``density_kg_m3``, ``surface_energy_j_m2`` (γ in air), a table ``[adhesion_work_j_m2]``
of measured w against partners, an optional ``[tau]`` (a shear strength with the w it
was fitted with and the partner it was measured on) and ``[sources]`` per field.

Two bodies in contact (Johnson, Contact Mechanics, eq. 4.22):
``1/E* = (1 − ν₁²)/E₁ + (1 − ν₂²)/E₂``; the softer body's hardness sets the
plasticity index; w is the measured value for the pair, else the estimate
``w ≈ 2√(γ₁γ₂)`` (Girifalco–Good with interaction parameter 1; Israelachvili,
Intermolecular and Surface Forces, ch. 17), and says which.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from functools import cache
from importlib import resources
from typing import Any

from feeder.errors import InputError

_NUMBERS = ("youngs_modulus_pa", "poisson_ratio", "hardness_pa", "density_kg_m3", "surface_energy_j_m2")


@dataclass(frozen=True)
class TauEntry:
    """A measured shear strength (Pa) ± band, the w (J/m²) it was fitted with, on ``partner``."""

    tau_pa: float
    tau_band_pa: float
    adhesion_work_j_m2: float
    partner: str


@dataclass(frozen=True)
class Material:
    """One material of the library (SI units); ``sources`` cites each field."""

    name: str
    youngs_modulus_pa: float
    poisson_ratio: float
    hardness_pa: float
    density_kg_m3: float
    surface_energy_j_m2: float
    adhesion_work_j_m2: dict[str, float] = field(default_factory=dict, hash=False, compare=False)
    tau: TauEntry | None = None
    aliases: tuple[str, ...] = ()
    sources: dict[str, str] = field(default_factory=dict, hash=False, compare=False)

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "aliases": list(self.aliases),
            "youngs_modulus_pa": self.youngs_modulus_pa,
            "poisson_ratio": self.poisson_ratio,
            "hardness_pa": self.hardness_pa,
            "density_kg_m3": self.density_kg_m3,
            "surface_energy_j_m2": self.surface_energy_j_m2,
            "adhesion_work_j_m2": dict(self.adhesion_work_j_m2),
            "tau_pa": self.tau.tau_pa if self.tau else None,
            "tau_band_pa": self.tau.tau_band_pa if self.tau else None,
            "tau_adhesion_work_j_m2": self.tau.adhesion_work_j_m2 if self.tau else None,
            "tau_partner": self.tau.partner if self.tau else None,
            "sources": dict(self.sources),
        }


def _parse(file_name: str, data: dict[str, Any]) -> Material:
    where = f"feeder/materials/{file_name}"
    try:
        numbers = {key: float(data[key]) for key in _NUMBERS}
        tau = data.get("tau")
        return Material(
            name=str(data["name"]),
            aliases=tuple(str(a) for a in data.get("aliases", ())),
            adhesion_work_j_m2={str(k): float(v) for k, v in data.get("adhesion_work_j_m2", {}).items()},
            tau=None
            if tau is None
            else TauEntry(
                float(tau["tau_pa"]),
                float(tau["tau_band_pa"]),
                float(tau["adhesion_work_j_m2"]),
                tau["partner"],
            ),
            sources={str(k): str(v) for k, v in data.get("sources", {}).items()},
            **numbers,
        )
    except (KeyError, TypeError, ValueError) as err:
        raise InputError(where, f"malformed material file: {err!r}") from None


@cache
def library() -> dict[str, Material]:
    """Every material of the package, by name."""
    out = {}
    for entry in sorted(resources.files(__name__).iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".toml"):
            material = _parse(entry.name, tomllib.loads(entry.read_text(encoding="utf-8")))
            out[material.name] = material
    return out


def material(name: str) -> Material:
    """The material called ``name`` or one of its aliases (case-insensitive); InputError if none."""
    key = name.strip().lower()
    for m in library().values():
        if key == m.name or key in m.aliases:
            return m
    known = ", ".join(
        f"{m.name} ({'/'.join(m.aliases)})" if m.aliases else m.name for m in library().values()
    )
    raise InputError("--material", f"unknown material {name[:40]!r}; known: {known}")


def effective_modulus_pa(a: Material, b: Material) -> float:
    """E* of two bodies: 1/E* = (1 − ν₁²)/E₁ + (1 − ν₂²)/E₂."""
    return 1.0 / (
        (1 - a.poisson_ratio**2) / a.youngs_modulus_pa + (1 - b.poisson_ratio**2) / b.youngs_modulus_pa
    )


def adhesion_work(a: Material, b: Material) -> tuple[float, str]:
    """w (J/m²) of the pair and where it comes from: measured, else 2√(γ₁γ₂)."""
    for first, second in ((a, b), (b, a)):
        if second.name in first.adhesion_work_j_m2:
            w = first.adhesion_work_j_m2[second.name]
            return w, f"measured ({first.sources.get('adhesion_work_j_m2', first.name)})"
    w = 2.0 * math.sqrt(a.surface_energy_j_m2 * b.surface_energy_j_m2)
    return w, "estimate 2·sqrt(γ1·γ2) from the surface energies in air (Girifalco–Good)"
