"""Numbers the paper reports (Paris, Haddab, Lutz, Rougeot), for comparison and tests.

Silicon parts 50 µm thick, ρ = 2330 kg/m³, g = 9.81 m/s².  Keys are part labels
``"LxWxT"`` in µm.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PaperRow:
    """One part of Tables I, III and IV–VI (SI units)."""

    weight_n: float
    real_area_flat_m2: float
    real_area_grooved_m2: float
    friction_flat_n: float
    friction_grooved_n: float | None
    tau_pa: float


PAPER_ROWS: dict[str, PaperRow] = {
    "300x300x50": PaperRow(1.0285e-7, 4.9734e-17, 3.7833e-17, 0.94e-6, 0.70e-6, 19.03e9),
    "200x200x50": PaperRow(4.5714e-8, 2.2104e-17, 1.6815e-17, 0.37e-6, None, 16.81e9),
    "100x100x50": PaperRow(1.1428e-8, 0.55259e-17, 0.42037e-17, 0.17e-6, None, 25.33e9),
    "80x80x50": PaperRow(7.3143e-9, 0.35366e-17, 0.26904e-17, 0.08e-6, None, 22.91e9),
}

SEPARATION_FLAT_M = 34.638e-9
SEPARATION_GROOVED_M = 34.600e-9
TAU_MEAN_PA = 22.18e9
TAU_SPREAD_PA = 3.15e9
RAW_FORCES_300_FLAT_N = (0.9759e-6, 0.9174e-6)
RAW_FORCES_300_GROOVED_N = (0.7078e-6, 0.6962e-6)
GROOVED_AREA_RATIO = 0.76
"""A_r grooved / A_r flat at the same weight, as printed in Table III."""
GROOVED_FRICTION_RATIO = 0.74
"""Measured friction grooved / flat for the 300×300 part."""
STEP_500_M = 3.3e-6
"""§V.B: sawtooth 100 Hz, 200 Vpp → 3.3 µm per step for a 500×500 µm part."""
