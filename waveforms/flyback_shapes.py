"""Compare flyback shapes on the full plant: step vs commanded flyback duration at one amplitude.

    .venv/bin/python waveforms/flyback_shapes.py [--part 500x500x50] [--frequency-hz 100]
        [--amplitude-vpp 150] [--small] [--out waveforms/flyback-shapes.png]

Linear and half-cosine flybacks of a commanded duration (from the fastest the
amplifier follows, ΔV/(I_max/C), resp. π/2 of that, upwards) against the
current-limited one (the command drops at once; the amplifier's current limit
sets the flyback).  The half-cosine has no corners (less ringing of the stack)
but, for the same duration, a higher peak speed and so a higher current.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from feeder.design import DesignProblem, fastest_flyback_s
from feeder.files import save_figure
from feeder.parts import Part
from feeder.waveform import Waveform

HERE = Path(__file__).resolve().parent


def run(part: str, frequency_hz: float, amplitude_vpp: float, small: bool, out: Path) -> dict:
    problem = DesignProblem(Part.parse(part))
    a_s = problem.breakaway_accel_m_s2()[0]
    r = problem.kinetic_ratio
    limited = problem.step_m(Waveform(frequency_hz, amplitude_vpp), a_s, r)
    curves = {}
    for shape in ("linear", "half-cosine"):
        t_min = fastest_flyback_s(shape, amplitude_vpp, problem.amplifier, problem.stack)
        durations = np.geomspace(t_min, 0.2 / frequency_hz, 5 if small else 30)
        waves = [Waveform(frequency_hz, amplitude_vpp, flyback_shape=shape, flyback_s=t) for t in durations]
        steps = [problem.step_m(w, a_s, r) for w in waves]
        curves[shape] = (durations, np.array(steps))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for shape, (durations, steps) in curves.items():
        ax.semilogx(durations * 1e3, steps * 1e6, "-o", ms=3, label=shape)
    ax.axhline(limited * 1e6, color="k", ls=":", label="current-limited")
    ax.set_xlabel("commanded flyback (ms)")
    ax.set_ylabel("step per period (µm)")
    ax.set_title(f"part {part} µm, {frequency_hz:g} Hz, {amplitude_vpp:g} Vpp, full plant", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, out)
    return {"current_limited_step_m": limited, "plot": str(out),
            **{f"{shape}_steps_m": steps.tolist() for shape, (_, steps) in curves.items()},
            **{f"{shape}_fastest_flyback_s": float(d[0]) for shape, (d, _) in curves.items()}}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", default="500x500x50")
    parser.add_argument("--frequency-hz", type=float, default=100.0)
    parser.add_argument("--amplitude-vpp", type=float, default=150.0)
    parser.add_argument("--small", action="store_true", help="few points (test suite)")
    parser.add_argument("--out", type=Path, default=HERE / "flyback-shapes.png")
    args = parser.parse_args(argv)
    print(json.dumps(run(args.part, args.frequency_hz, args.amplitude_vpp, args.small, args.out), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
