"""The half-cosine flyback entry of ``stickslip`` under its own name (issue 14's acceptance key).

``ratio`` = solve_ivp's time per period / the exact event-driven solver's, at
equal accuracy (see benchmarks/stickslip.py for the method).
"""

from __future__ import annotations

from stickslip import compare, ours

from feeder.plant.ideal_plate import COSINE_PIECES


def run(quick: bool) -> dict:
    periods = 20 if quick else 100
    reference = ours(2, pieces=16 * COSINE_PIECES)[-1]
    ratio, t_ours, t_base, err, base_err, rtol = compare("half-cosine", reference, periods, quick)
    return {
        "ratio": ratio,
        "periods_per_s": 1 / t_ours,
        "solve_ivp_periods_per_s": 1 / t_base,
        "our_relative_error": err,
        "solve_ivp_relative_error": base_err,
        "solve_ivp_rtol": rtol,
    }
