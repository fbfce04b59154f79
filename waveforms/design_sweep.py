"""Waveform design sweep: predicted step vs flyback time, amplitude and frequency (paper §V.B).

    .venv/bin/python waveforms/design_sweep.py [--part 500x500x50] [--out waveforms/design-sweep.png] [--json]

Panels (a_s from the contact model, F_k/F_s = 0.8, stack 0.07 µm/V):

1. flyback time × amplitude map, linear flyback on the ideal plate (batch solver,
   all grid points at once), with the closed-form threshold S(1/t_r + 1/t_f) = a_k·t_f;
2. step vs flyback time at 200 Vpp, 100 Hz: linear (closed form and batch
   solver) and half-cosine (batch solver);
3. step vs amplitude: linear flybacks of fixed duration (ideal plate; each has a
   threshold voltage below which nothing moves) and the current-limited
   flyback on the full plant (amplifier + stack dynamics);
4. step vs frequency at 200 Vpp: current-limited on the full plant, linear
   0.35 ms on the ideal plate (batch solver: above 1.43 kHz the rise is shorter
   than the flyback, the part never re-sticks, the closed form does not apply and
   the steady step, reached after several periods, reverses: −18 µm at 2 kHz).

Prints the threshold voltages and the paper point as one JSON object with --json.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from feeder.contact.breakaway import contact
from feeder.parts import Part
from feeder.plant.ideal_plate import linear_flyback_step
from feeder.plant.plant import run_waveform
from feeder.plant.stack import StackParameters
from feeder.plant.steady_state import ideal_steady_steps, steady_start
from feeder.plant.stick_slip import DEFAULT_KINETIC_RATIO, Friction
from feeder.waveform import Waveform

HERE = Path(__file__).resolve().parent


def batch_steps(stroke: np.ndarray, freq: np.ndarray, t_f: np.ndarray, shape: str, a_s: float) -> np.ndarray:
    """Steady step per parameter set on the ideal plate (batch mode: all sets at once; a set
    whose part slides through whole periods is run until its step settles)."""
    return ideal_steady_steps(stroke, freq, t_f, shape, a_s, DEFAULT_KINETIC_RATIO).step_m


def plant_step(friction: Friction, frequency_hz: float, amplitude_vpp: float) -> float:
    """Steady step of the current-limited sawtooth on the full plant (the settled periods of 4)."""
    steps = run_waveform(
        friction, Waveform(frequency_hz=frequency_hz, amplitude_vpp=amplitude_vpp), 4
    ).steps_m
    start, _ = steady_start(steps)
    return float(steps[start[0] :].mean())


def sweep(part: Part) -> dict:
    gain = StackParameters().gain_m_per_v
    a_s = contact(part).breakaway_accel_m_s2
    a_k = DEFAULT_KINETIC_RATIO * a_s
    friction = Friction(a_s)
    volts = np.linspace(5, 200, 60)
    flybacks = np.geomspace(2e-5, 1.2e-3, 70)
    vv, ff = np.meshgrid(volts, flybacks)
    grid = batch_steps(gain * vv.ravel(), np.full(vv.size, 100.0), ff.ravel(), "linear", a_s).reshape(
        vv.shape
    )
    fly_lin = batch_steps(
        np.full(flybacks.size, gain * 200), np.full(flybacks.size, 100.0), flybacks, "linear", a_s
    )
    fly_cos = batch_steps(
        np.full(flybacks.size, gain * 200), np.full(flybacks.size, 100.0), flybacks, "half-cosine", a_s
    )
    fixed = [1e-4, 2e-4, 3.5e-4]
    amp_lin = {t: linear_flyback_step(gain * volts, 0.01 - t, t, a_k) for t in fixed}
    thresholds = {f"{t * 1e6:g}us": float(a_k * t**2 / (gain * (1 + t / (0.01 - t)))) for t in fixed}
    amp_plant = np.array([plant_step(friction, frequency_hz=100.0, amplitude_vpp=v) for v in volts])
    freqs = np.geomspace(10, 2000, 30)
    freq_plant = np.array([plant_step(friction, frequency_hz=f, amplitude_vpp=200.0) for f in freqs])
    freq_lin = batch_steps(np.full(freqs.size, gain * 200), freqs, np.full(freqs.size, 3.5e-4), "linear", a_s)
    return {
        "a_s": a_s,
        "volts": volts,
        "flybacks": flybacks,
        "grid": grid,
        "fly_lin": fly_lin,
        "fly_closed": linear_flyback_step(gain * 200, 0.01 - flybacks, flybacks, a_k),
        "fly_cos": fly_cos,
        "amp_lin": amp_lin,
        "thresholds": thresholds,
        "amp_plant": amp_plant,
        "freqs": freqs,
        "freq_plant": freq_plant,
        "freq_lin": freq_lin,
        "paper_step": plant_step(friction, frequency_hz=100.0, amplitude_vpp=200.0),
    }


def plot(data: dict, part: Part, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    um = 1e6
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    ax = axes[0, 0]
    mesh = ax.pcolormesh(data["volts"], data["flybacks"] * 1e3, data["grid"] * um, shading="auto")
    ax.contour(
        data["volts"],
        data["flybacks"] * 1e3,
        data["grid"] * um,
        levels=[1e-3, 3.3],
        colors=["w", "r"],
        linewidths=1,
    )
    fig.colorbar(mesh, ax=ax, label="step (µm)")
    ax.set_yscale("log")
    ax.set_xlabel("amplitude (Vpp)")
    ax.set_ylabel("linear flyback (ms)")
    ax.set_title("ideal plate, 100 Hz: white = threshold, red = 3.3 µm", fontsize=9)
    ax = axes[0, 1]
    ax.semilogx(
        data["flybacks"] * 1e3, data["fly_closed"] * um, "k-", lw=3, alpha=0.3, label="linear, closed form"
    )
    ax.semilogx(data["flybacks"] * 1e3, data["fly_lin"] * um, "C0--", label="linear, solver")
    ax.semilogx(data["flybacks"] * 1e3, data["fly_cos"] * um, "C1-", label="half-cosine, solver")
    ax.set_xlabel("flyback time (ms)")
    ax.set_ylabel("step (µm)")
    ax.set_title("200 Vpp, 100 Hz, ideal plate", fontsize=9)
    ax.legend(fontsize=8)
    ax = axes[1, 0]
    for t_f, steps in data["amp_lin"].items():
        ax.plot(data["volts"], steps * um, label=f"linear {t_f * 1e3:g} ms (ideal)")
    ax.plot(data["volts"], data["amp_plant"] * um, "k-", label="current-limited (plant)")
    ax.axhline(3.3, color="r", lw=0.8, ls=":")
    ax.set_xlabel("amplitude (Vpp)")
    ax.set_ylabel("step (µm)")
    ax.set_title("100 Hz: threshold voltage of fixed flybacks", fontsize=9)
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    ax.semilogx(data["freqs"], data["freq_plant"] * um, "k-", label="current-limited (plant)")
    ax.semilogx(data["freqs"], data["freq_lin"] * um, "C0--", label="linear 0.35 ms (ideal)")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("step (µm)")
    ax.set_title("200 Vpp", fontsize=9)
    ax.legend(fontsize=8)
    fig.suptitle(
        f"predicted step, part {part.label} µm, a_s = {data['a_s']:.4g} m/s², "
        f"F_k/F_s = {DEFAULT_KINETIC_RATIO}"
    )
    fig.tight_layout()
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", default="500x500x50", help="LxWxT in µm (default 500x500x50)")
    parser.add_argument("--out", type=Path, default=HERE / "design-sweep.png", help="PNG to write")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    part = Part.parse(args.part)
    if not args.json:
        print("sweeping (batch solver and plant) ...", file=sys.stderr)
    data = sweep(part)
    plot(data, part, args.out)
    summary = {
        "part": part.label,
        "breakaway_accel_m_s2": data["a_s"],
        "threshold_voltage_v": data["thresholds"],
        "paper_waveform_step_m": data["paper_step"],
        "plot": str(args.out),
    }
    print(json.dumps(summary, indent=2) if args.json else "\n".join(f"{k}: {v}" for k, v in summary.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
