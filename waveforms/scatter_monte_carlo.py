"""Scatter Monte Carlo: where a burst of N steps ends when a_s scatters from stick to stick.

    .venv/bin/python waveforms/scatter_monte_carlo.py [--waveform waveforms/paper-100hz-200vpp.toml]
        [--part 500x500x50] [--scatter 0.05] [--steps 50] [--runs 200] [--small]
        [--out waveforms/scatter-monte-carlo.png]

Each run is the full plant with its own seed (a_s redrawn at every re-stick
with relative std ``scatter``); the histogram of the burst's net displacement
is set against N × the planner's predicted step and its band (τ and F_k/F_s).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from feeder.design import DesignProblem
from feeder.files import save_figure
from feeder.parts import Part
from feeder.plant.plant import run_waveform
from feeder.plant.stick_slip import Friction
from feeder.waveform import load_waveform

HERE = Path(__file__).resolve().parent


def run(waveform_path: Path, part: str, scatter: float, steps: int, runs: int, out: Path) -> dict:
    waveform = load_waveform(waveform_path)
    problem = DesignProblem(Part.parse(part))
    a_s = problem.breakaway_accel_m_s2()[0]
    prediction = problem.predict(waveform)
    friction = Friction(a_s, problem.kinetic_ratio)
    nets = np.array([run_waveform(friction, waveform, steps, scatter=scatter, seed=seed).net_displacement_m
                     for seed in range(runs)])  # fmt: skip

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.hist(
        nets * 1e6, bins=max(5, runs // 10), color="C0", alpha=0.7, label=f"{runs} runs, scatter {scatter:g}"
    )
    ax.axvline(steps * prediction.step_m * 1e6, color="k", label="N × predicted step")
    lo, hi = prediction.band_m
    ax.axvspan(steps * lo * 1e6, steps * hi * 1e6, color="0.8", alpha=0.4, label="N × band (τ, F_k/F_s)")
    ax.set_xlabel(f"net displacement after {steps} steps (µm)")
    ax.set_ylabel("runs")
    ax.set_title(f"part {part} µm, {waveform_path.name}", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, out)
    return {"net_mean_m": float(nets.mean()), "net_std_m": float(nets.std(ddof=1)),
            "predicted_net_m": steps * prediction.step_m,
            "predicted_net_band_m": [steps * lo, steps * hi], "plot": str(out)}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--waveform", type=Path, default=HERE / "paper-100hz-200vpp.toml")
    parser.add_argument("--part", default="500x500x50")
    parser.add_argument("--scatter", type=float, default=0.05)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--small", action="store_true", help="10 steps × 12 runs (test suite)")
    parser.add_argument("--out", type=Path, default=HERE / "scatter-monte-carlo.png")
    args = parser.parse_args(argv)
    steps, runs = (10, 12) if args.small else (args.steps, args.runs)
    print(json.dumps(run(args.waveform, args.part, args.scatter, steps, runs, args.out), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
