"""The two waveforms the daemon steps with, from the planner (paper §V.B; DESIGN §4).

*Coarse*: the planner's fastest waveform for a long move (largest step the
margins allow).  *Fine*: same frequency, amplitude planned so that one step is
the tolerance, so the last stretch ends within half a fine step of the target.
Each comes with the predicted step and its band (τ band, F_k/F_s band), which
seed the step estimators.
"""

from __future__ import annotations

from feeder.daemon.config import DaemonConfig
from feeder.daemon.control_loop import COARSE, FINE, StepMode
from feeder.drivers.amplifier import DriveSettings
from feeder.parts import Part, Support
from feeder.planner import Plan, plan
from feeder.surface.parameters import SurfaceParameters

COARSE_PLAN_DISTANCE_M = 1e-3
"""A move long enough that the planner picks its largest-step waveform."""


def _mode(name: str, p: Plan) -> StepMode:
    low, high = sorted(abs(b) for b in p.predicted_step_band_m)
    settings = DriveSettings(
        frequency_hz=p.frequency_hz, amplitude_v=p.amplitude_vpp, flyback_shape=p.flyback_shape
    )
    return StepMode(name, settings, abs(p.predicted_step_m), (low, high))


def plan_step_modes(
    config: DaemonConfig, surface: SurfaceParameters, frequency_hz: float | None = None
) -> dict[str, StepMode]:
    """Coarse and fine :class:`StepMode` for the configuration's part, support, τ, amplifier, stack and
    tolerance (at ``frequency_hz``, else the planner's fastest); :class:`~feeder.errors.InputError`
    if unplannable."""
    part, support, tau_pa, amplifier = config.part, config.support, config.tau_pa, config.amplifier.limits
    stack = config.planning_stack
    coarse = plan(
        part,
        support,
        surface,
        tau_pa,
        amplifier,
        COARSE_PLAN_DISTANCE_M,
        stack=stack,
        frequency_hz=frequency_hz,
    )
    fine = plan(
        part, support, surface, tau_pa, amplifier, config.loop.tolerance_m, stack=stack,
        frequency_hz=coarse.frequency_hz,
    )  # fmt: skip
    return {COARSE: _mode(COARSE, coarse), FINE: _mode(FINE, fine)}


def calibration_key(part: Part, support: Support, modes: dict[str, StepMode]) -> str:
    """Names what a learned step belongs to: part, support and both waveforms."""
    c, f = modes[COARSE].settings, modes[FINE].settings
    return f"{part.label}/{support.kind}/{c.frequency_hz:g}Hz/{c.amplitude_v:.3f}V/{f.amplitude_v:.3f}V"
