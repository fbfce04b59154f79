"""The planar plant: three DAC channels (x, y, θ) → amplifier → stack → plate → parts' poses (DESIGN §9).

Each axis has its own amplifier output stage and stack model
(:class:`~feeder.plant.plant.Plant` without the contact); the θ stack pushes
the plate round O at ``lever_arm_m``, so the plate turns by (stack
displacement)/(lever arm).  The parts ride the plate with the planar
stick-slip of :class:`~feeder.plant.planar.PlanarStickSlip`, fed the three
plate velocities sample by sample (acceleration held between samples, as the
1-D plant does).
"""

from __future__ import annotations

import numpy as np

from feeder.errors import InputError
from feeder.plant import kernels, planar_arrays
from feeder.plant.amplifier import AmplifierLimits, OutputStage
from feeder.plant.planar import PlanarPart, PlanarStickSlip, Pose
from feeder.plant.plant import DEFAULT_SAMPLE_RATE_HZ
from feeder.plant.stack import StackFilter, StackParameters

DEFAULT_LEVER_ARM_M = 2e-3
"""Radius at which the θ stack drives the plate: 14 µm of stroke turn it by 7 mrad."""
STREAMING_RTOL = 1e-6
"""Relative tolerance of the slip episodes in the streaming plant: over 0.2 s of the paper's
waveform on x, y and θ (parts at O, 2 mm from it, rotated off it) the poses stay within
1e-10 m and 1e-6 rad of rtol 1e-10 (1e-8: 3e-12 m, 1e-8 rad), ~1.5× faster than 1e-8."""

_STATES = slice(kernels.DRIVE_STATES, kernels.DRIVE_STATES + 2 * kernels.FILTER_ORDER)
"""Columns of the compiled path's drive array (:func:`.planar_kernels.run_plant`)."""


class PlanarPlant:
    """Parts on a plate driven by three stick-slip channels, streaming at ``sample_rate_hz``.

    parts: the parts and their poses (plate frame, origin O); amplifier,
    stack: one model, used for each of the three channels; lever_arm_m: the
    θ stack's radius about O (m); rtol: of the slip episodes (:class:`.PlanarStickSlip`).
    """

    def __init__(
        self,
        parts: list[PlanarPart],
        amplifier: AmplifierLimits | None = None,
        stack: StackParameters | None = None,
        sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
        lever_arm_m: float = DEFAULT_LEVER_ARM_M,
        rtol: float = STREAMING_RTOL,
    ) -> None:
        if not (np.isfinite(lever_arm_m) and lever_arm_m > 0):
            raise InputError("lever_arm_m", f"must be a positive number, got {lever_arm_m!r}")
        self.amplifier = amplifier or AmplifierLimits()
        self.stack = stack or StackParameters()
        self.sample_rate_hz = float(sample_rate_hz)
        self.lever_arm_m = float(lever_arm_m)
        capacitance = self.stack.capacitance_f
        self.outputs = [OutputStage(self.amplifier, capacitance, sample_rate_hz) for _ in range(3)]
        self.mechanics = [StackFilter(self.stack, sample_rate_hz) for _ in range(3)]
        self.contact = PlanarStickSlip(parts, rtol=rtol)
        self._scale = np.array([[1.0], [1.0], [1.0 / self.lever_arm_m]])  # stack m → plate m, m, rad
        self._compilable = self.mechanics[0].order == kernels.FILTER_ORDER and self.contact.compiled
        self._drive: np.ndarray | None = None
        """Per channel: coefficients, filter states, voltage, scale (:func:`.planar_kernels.run_plant`)
        while the compiled path holds them."""

    @property
    def plate_pose(self) -> Pose:
        """(x_O, y_O, θ) of the plate now (m, m, rad), zero at the start."""
        return self.contact.plate_pose

    @property
    def output_voltages_v(self) -> tuple[float, float, float]:
        if self._drive is not None:
            x, y, theta = self._drive[:, planar_arrays.DRIVE_VOLTS].tolist()
            return x, y, theta
        return (self.outputs[0].voltage_v, self.outputs[1].voltage_v, self.outputs[2].voltage_v)

    def poses(self) -> list[Pose]:
        """The parts' poses in the plate frame now."""
        return self.contact.poses()

    def lab_poses(self) -> list[Pose]:
        """The parts' poses in the lab frame now (what a camera sees)."""
        return self.contact.lab_poses()

    def advance(self, command_volts: np.ndarray) -> np.ndarray:
        """Command samples (3, n) in V for x, y, θ; returns the parts' lab poses (parts, n, 3)."""
        command = np.asarray(command_volts, dtype=float)
        if command.ndim != 2 or command.shape[0] != 3:
            raise InputError("command_volts", f"expected shape (3, n), got {command.shape}")
        if self._compilable and kernels.enabled():
            return self._advance_compiled(command)
        self._sync_objects()
        velocity = np.empty(command.shape)
        for k in range(3):
            _, velocity[k] = self.mechanics[k].advance(self.outputs[k].advance(command[k]))
        velocity *= self._scale
        return self.contact.advance_sampled(velocity, self.sample_rate_hz)

    def _advance_compiled(self, command: np.ndarray) -> np.ndarray:
        """:meth:`advance` in one compiled call (:func:`.planar_kernels.run_plant`)."""
        if self._drive is None:
            self._drive = np.array([np.concatenate([[o.limits.v_min_v, o.limits.v_max_v, o.max_step_v],
                                                    m.coefficients(), m.states, [o.voltage_v, k]])
                                    for o, m, k in zip(self.outputs, self.mechanics, self._scale[:, 0],
                                                       strict=True)])  # fmt: skip
        if not command.flags.c_contiguous:
            command = np.ascontiguousarray(command)
        return self.contact.advance_driven(command, self._drive, self.sample_rate_hz)

    def _sync_objects(self) -> None:
        """Hand the compiled path's filter states and voltages back to the stage objects."""
        if self._drive is not None:
            for k in range(3):
                self.mechanics[k].states = self._drive[k, _STATES].copy()
                self.outputs[k].voltage_v = float(self._drive[k, planar_arrays.DRIVE_VOLTS])
            self._drive = None
