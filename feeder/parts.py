"""Parts (silicon cuboids) and the supports they rest on (paper §IV.A, Table I)."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from feeder.errors import InputError

SILICON_DENSITY_KG_M3 = 2330.0
GRAVITY_M_S2 = 9.81

PART_SIDE_RANGE_UM = (1.0, 100e3)
"""Accepted length and width of a part in µm (1 µm–100 mm)."""
PART_THICKNESS_RANGE_UM = (1.0, 10e3)
"""Accepted thickness of a part in µm (1 µm–10 mm)."""
DENSITY_RANGE_KG_M3 = (1.0, 1e5)
"""Accepted part density in kg/m³."""

_NUMBER = r"(\d+(?:\.\d*)?|\.\d+)"
_PART_RE = re.compile(rf"^\s*{_NUMBER}\s*[x×]\s*{_NUMBER}\s*[x×]\s*{_NUMBER}\s*$", re.IGNORECASE)


@dataclass(frozen=True)
class Part:
    """A cuboid part lying flat: length × width footprint, thickness vertical (metres)."""

    length_m: float
    width_m: float
    thickness_m: float
    density_kg_m3: float = SILICON_DENSITY_KG_M3

    def __post_init__(self) -> None:
        for name in ("length_m", "width_m", "thickness_m", "density_kg_m3"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(name, f"must be a positive number, got {value!r}")

    @classmethod
    def parse(cls, text: str, density_kg_m3: float = SILICON_DENSITY_KG_M3) -> Part:
        """``"300x300x50"`` (µm, decimals allowed) → Part."""
        match = _PART_RE.match(text)
        if match is None:
            raise InputError(
                "--part", f"expected LxWxT in µm with positive numbers (e.g. 300x300x50), got {text!r}"
            )
        length, width, thickness = (float(g) for g in match.groups())
        low, high = PART_SIDE_RANGE_UM
        if not (low <= length <= high and low <= width <= high):
            raise InputError("--part", f"length and width must be {low:g}–{high:g} µm, got {text!r}")
        low, high = PART_THICKNESS_RANGE_UM
        if not low <= thickness <= high:
            raise InputError("--part", f"thickness must be {low:g}–{high:g} µm, got {text!r}")
        return cls(length * 1e-6, width * 1e-6, thickness * 1e-6, density_kg_m3)

    @property
    def label(self) -> str:
        """``"300x300x50"`` in µm."""
        return "x".join(f"{v * 1e6:g}" for v in (self.length_m, self.width_m, self.thickness_m))

    @property
    def footprint_m2(self) -> float:
        return self.length_m * self.width_m

    @property
    def mass_kg(self) -> float:
        return self.density_kg_m3 * self.footprint_m2 * self.thickness_m

    @property
    def weight_n(self) -> float:
        """Weight in newtons (Table I), g = 9.81 m/s²."""
        return self.mass_kg * GRAVITY_M_S2


@dataclass(frozen=True)
class Support:
    """The plate surface under the part.

    ``flat``: the whole footprint is nominal contact area.
    ``grooved``: lands of width ``land_width_m`` every ``groove_period_m``; the
    nominal-area fraction is land/period (the paper's grooved support: 0.5).
    """

    kind: str = "flat"
    groove_period_m: float = 20e-6
    land_width_m: float = 10e-6

    KINDS = ("flat", "grooved")

    def __post_init__(self) -> None:
        if self.kind not in self.KINDS:
            raise InputError("--support", f"expected one of {', '.join(self.KINDS)}, got {self.kind!r}")
        if self.kind == "grooved":
            if not (self.groove_period_m > 0 and math.isfinite(self.groove_period_m)):
                raise InputError("groove_period_m", "must be a positive number")
            if not (0 < self.land_width_m <= self.groove_period_m):
                raise InputError("land_width_m", "must be positive and at most the groove period")

    @classmethod
    def parse(cls, text: str) -> Support:
        return cls(kind=text.strip().lower())

    @property
    def area_fraction(self) -> float:
        """Nominal contact area / part footprint."""
        return 1.0 if self.kind == "flat" else self.land_width_m / self.groove_period_m

    def nominal_area_m2(self, part: Part) -> float:
        return part.footprint_m2 * self.area_fraction


FLAT = Support("flat")
GROOVED = Support("grooved")
