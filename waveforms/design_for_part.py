"""Design the best waveform for a part on an amplifier, write the design file, plot step vs amplitude.

    .venv/bin/python waveforms/design_for_part.py [--part 500x500x50] [--amplifier paper]
        [--objective max-step] [--small] [--out waveforms/design-for-part.png]

Uses :func:`feeder.design.design_waveform` (full plant model), writes the
design file beside the figure (``.toml``) and plots the step of the designed
frequency and flyback shape against amplitude, with the paper's waveform for
comparison.  ``--small``: a coarse search (for the test suite).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from feeder.design import DesignProblem, design_waveform, write_design
from feeder.files import save_figure
from feeder.parts import Part
from feeder.plant.amplifier import resolve_amplifier
from feeder.waveform import Waveform

HERE = Path(__file__).resolve().parent


def run(part: str, amplifier: str, objective: str, small: bool, out: Path) -> dict:
    model, limits = resolve_amplifier(amplifier)
    if small:  # a coarse search above 50 Hz (slow sawtooths cost the most to simulate)
        limits = replace(limits, min_frequency_hz=max(limits.min_frequency_hz, 50.0))
    problem = DesignProblem(Part.parse(part), amplifier_model=model, amplifier=limits)
    effort = {"grid_points": (3, 3), "refine_evaluations": 8, "shapes": ("current-limited",)} if small else {}
    design = design_waveform(problem, objective, **effort)  # type: ignore[arg-type]
    write_design(out.with_suffix(".toml"), problem, design.waveform, design.prediction, design.tables(),
                 written_by="waveforms/design_for_part.py")  # fmt: skip
    a_s = problem.breakaway_accel_m_s2()[0]
    top = min(limits.max_amplitude_vpp, 200.0)
    volts = np.linspace(0.2 * top, top, 6 if small else 25)
    steps = [problem.step_m(replace(design.waveform, amplitude_vpp=v), a_s, problem.kinetic_ratio)
             for v in volts]  # fmt: skip
    paper = problem.step_m(Waveform(100.0, top), a_s, problem.kinetic_ratio)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w = design.waveform
    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.plot(volts, np.array(steps) * 1e6, "C0-o", ms=3, label=f"{w.frequency_hz:.4g} Hz, {w.flyback_shape}")
    ax.plot([w.amplitude_vpp], [design.predicted_step_m * 1e6], "r*", ms=12, label="design")
    lo, hi = design.predicted_step_band_m
    ax.errorbar(
        [w.amplitude_vpp],
        [design.predicted_step_m * 1e6],
        fmt="none",
        ecolor="r",
        yerr=[[(design.predicted_step_m - lo) * 1e6], [(hi - design.predicted_step_m) * 1e6]],
    )
    ax.axhline(paper * 1e6, color="k", ls=":", label=f"100 Hz, {top:g} Vpp (paper's waveform)")
    ax.set_xlabel("amplitude (Vpp)")
    ax.set_ylabel("step per period (µm)")
    ax.set_title(f"part {part} µm, amplifier {model}, objective {objective}", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, out)
    return {**design.to_json(), "paper_waveform_step_m": paper, "plot": str(out),
            "design_file": str(out.with_suffix(".toml"))}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", default="500x500x50")
    parser.add_argument("--amplifier", default="paper", help="anc300, paper or a TOML file")
    parser.add_argument("--objective", default="max-step", choices=("max-step", "min-scatter", "max-speed"))
    parser.add_argument("--small", action="store_true", help="coarse search (test suite)")
    parser.add_argument("--out", type=Path, default=HERE / "design-for-part.png")
    args = parser.parse_args(argv)
    print(json.dumps(run(args.part, args.amplifier, args.objective, args.small, args.out), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
