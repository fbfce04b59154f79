"""Step vs part size for one waveform, without and with DMT adhesion (DESIGN §2, §11).

    .venv/bin/python waveforms/step_vs_part_size.py [--waveform waveforms/paper-100hz-200vpp.toml]
        [--adhesion-work 0.1] [--small] [--out waveforms/step-vs-part-size.png]

Square silicon parts, 50 µm thick, on the flat support.  Without adhesion the
nominal pressure ρ·g·t is the same for every size, so a_break and the step are
the same for every size: a flat line, and the model says so.  DMT adhesion adds
a pull that scales with the nominal area, as the weight does at a fixed
thickness, and τ is the one fitted with that w to the paper's forces: the
τ–w pair keeps a_break, so the step stays (flat in size again).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from feeder.design import DesignProblem
from feeder.files import save_figure
from feeder.parts import Part
from feeder.surface.parameters import DEFAULT_SURFACE
from feeder.waveform import load_waveform

HERE = Path(__file__).resolve().parent


def run(waveform_path: Path, adhesion_work_j_m2: float, small: bool, out: Path) -> dict:
    waveform = load_waveform(waveform_path)
    sides = np.linspace(80, 500, 4 if small else 15)
    curves = {}
    for w in (0.0, adhesion_work_j_m2):
        surface = replace(DEFAULT_SURFACE, adhesion_work_j_m2=w)
        steps, accels = [], []
        for side in sides:
            problem = DesignProblem(Part.parse(f"{side:g}x{side:g}x50"), surface=surface)
            a_s = problem.breakaway_accel_m_s2()[0]
            accels.append(a_s)
            steps.append(problem.step_m(waveform, a_s, problem.kinetic_ratio))
        curves[w] = (np.array(steps), np.array(accels))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    for w, (steps, accels) in curves.items():
        ax1.plot(sides, steps * 1e6, "-o", ms=3, label=f"w = {w:g} J/m²")
        ax2.plot(sides, accels, "-o", ms=3, label=f"w = {w:g} J/m²")
    ax1.set_xlabel("part side (µm), 50 µm thick")
    ax1.set_ylabel("step per period (µm)")
    ax1.set_title(f"{waveform_path.name}, full plant", fontsize=9)
    ax2.set_xlabel("part side (µm)")
    ax2.set_ylabel("a_break = τ·A_r/m (m/s²)")
    for ax in (ax1, ax2):
        ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, out)
    return {"sides_um": sides.tolist(), "plot": str(out),
            **{f"steps_m_w{w:g}": steps.tolist() for w, (steps, _) in curves.items()}}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--waveform", type=Path, default=HERE / "paper-100hz-200vpp.toml")
    parser.add_argument("--adhesion-work", type=float, default=0.1, help="w in J/m² (default 0.1)")
    parser.add_argument("--small", action="store_true", help="few sizes (test suite)")
    parser.add_argument("--out", type=Path, default=HERE / "step-vs-part-size.png")
    args = parser.parse_args(argv)
    print(json.dumps(run(args.waveform, args.adhesion_work, args.small, args.out), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
