"""Piezo stack + plate: a linear model built with python-control, discretised for streaming.

Voltage V at the stack → plate position x (DESIGN §4):

    X(s)/V(s) = g · ω_a/(s + ω_a) · ω_n²/(s² + 2ζω_n·s + ω_n²)

- g: stack gain (m/V), free stroke per volt;
- ω_a = 1/(R_out·C): the amplifier's output resistance into the stack
  capacitance C (a first-order low-pass that rounds the voltage's corners);
- ω_n, ζ: the stack's first axial resonance loaded by the plate, and its damping.

Defaults (docs/plant.md): g = 0.07 µm/V (14 µm at the paper's 200 V), C = 1.0 µF,
R_out = 8 Ω (20 kHz corner), loaded resonance 30 kHz (a 74–150 kHz stack
carrying a plate a few times its own effective mass), ζ = 0.1.

:class:`StackFilter` runs the model discretised with a first-order hold (exact
for piecewise-linear voltages, which is what a slope-limited amplifier produces
between samples) as two ``scipy.signal.lfilter`` calls with carried state.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

from feeder.errors import InputError
from feeder.files import toml_number

if TYPE_CHECKING:
    import control

# python-control and scipy.signal (~2 s to import, matplotlib with them) are imported where a
# model is built or filtered: the commands that only name a stack (``feeder simulate --help``,
# firmware_sim's option checks) start without them.


STACK_RANGES: dict[str, tuple[float, float]] = {
    "gain_m_per_v": (1e-12, 1e-3),
    "capacitance_f": (1e-12, 1e-3),
    "output_resistance_ohm": (0.0, 1e6),
    "resonance_hz": (100.0, 1e7),
    "damping_ratio": (1e-3, 10.0),
}
"""Accepted values of each :class:`StackParameters` field where a user states a stack (the
daemon's ``[stack]``, firmware_sim's ``--stack-*`` options)."""
STACK_FIELDS: dict[str, tuple[str, str]] = {
    "gain_m_per_v": ("m/V", "the stacks' free stroke per volt"),
    "capacitance_f": (
        "F",
        "the stacks' capacitance: with the current limit it sets the flyback, t_f ≈ C·ΔV/I_max",
    ),
    "resonance_hz": ("Hz", "the stacks' first axial resonance, loaded by the plate"),
    "damping_ratio": ("", "the damping ratio of that resonance"),
    "output_resistance_ohm": ("Ω", "the amplifier's output resistance into the stacks"),
}
"""Each field's unit and meaning, for the options that state it (``--stack-*``)."""


@dataclass(frozen=True)
class StackParameters:
    """Stack and plate: gain (m/V), capacitance (F), output resistance (Ω), resonance (Hz), ζ."""

    gain_m_per_v: float = 0.07e-6
    capacitance_f: float = 1.0e-6
    output_resistance_ohm: float = 8.0
    resonance_hz: float = 30.0e3
    damping_ratio: float = 0.1

    def __post_init__(self) -> None:
        for name in ("gain_m_per_v", "capacitance_f", "resonance_hz", "damping_ratio"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(name, f"must be a positive number, got {value!r}")
        if not (math.isfinite(self.output_resistance_ohm) and self.output_resistance_ohm >= 0):
            raise InputError("output_resistance_ohm", "must be a non-negative number")

    def position_model(self) -> control.TransferFunction:
        """X(s)/V(s) in m/V."""
        import control

        w_n = 2 * math.pi * self.resonance_hz
        plant = control.tf([self.gain_m_per_v * w_n**2], [1.0, 2 * self.damping_ratio * w_n, w_n**2])
        if self.output_resistance_ohm > 0:
            w_a = 1.0 / (self.output_resistance_ohm * self.capacitance_f)
            plant = control.tf([w_a], [1.0, w_a]) * plant
        return plant

    def state_space(self) -> control.StateSpace:
        """Continuous model with outputs [position (m), velocity (m/s)]."""
        import control

        position = control.ss(self.position_model())
        a, b, c, d = position.A, position.B, position.C, position.D
        # velocity = d/dt (C x) = C A x + C B u (D = 0: the model's relative degree is ≥ 2)
        return control.ss(a, b, np.vstack([c, c @ a]), np.vstack([d, c @ b]))

    def discrete(self, sample_rate_hz: float) -> control.StateSpace:
        """First-order-hold discretisation at ``sample_rate_hz``."""
        import control

        return control.sample_system(self.state_space(), 1.0 / sample_rate_hz, method="foh")


def stack_from_table(table: Mapping[str, Any], where: str) -> StackParameters:
    """StackParameters from a TOML table of its fields (a design file's ``[stack]``; missing
    fields: the defaults), each within :data:`STACK_RANGES`; ``where`` prefixes the errors' field."""
    values: dict[str, float] = {}
    for key, value in table.items():
        if key not in STACK_RANGES:
            raise InputError(f"{where}{key}", f"unknown field; known: {', '.join(STACK_RANGES)}")
        number = toml_number(f"{where}{key}", value)
        low, high = STACK_RANGES[key]
        if not (math.isfinite(number) and low <= number <= high):
            raise InputError(f"{where}{key}", f"{number:g} is outside [{low:g}, {high:g}]")
        values[key] = number
    return StackParameters(**values)


def _transfer_rows(system: control.StateSpace) -> list[tuple[np.ndarray, np.ndarray]]:
    """(b, a) of each output of a single-input discrete system, for lfilter."""
    import control

    rows = []
    for k in range(system.noutputs):
        tf = control.ss2tf(system[k, 0])
        rows.append((np.atleast_1d(np.squeeze(tf.num[0][0])), np.atleast_1d(np.squeeze(tf.den[0][0]))))
    return rows


class StackFilter:
    """Streaming stack + plate: voltage samples → plate position (m) and velocity (m/s).

    Starts at rest at ``initial_v`` (position g·V).
    """

    def __init__(self, stack: StackParameters, sample_rate_hz: float, initial_v: float = 0.0) -> None:
        self.stack = stack
        self.sample_rate_hz = sample_rate_hz
        self._rows, unit_states = _filter_design(stack, float(sample_rate_hz))
        self._states = [zi * initial_v for zi in unit_states]

    @property
    def order(self) -> int:
        """The filters' order (both rows share the denominator, so their states match)."""
        return self._states[0].size

    def coefficients(self) -> np.ndarray:
        """b and a of the position row, then of the velocity row, a[0] = 1, each padded to order + 1."""
        n = self.order + 1
        return np.concatenate([np.pad(c / a[0], (0, n - c.size)) for b, a in self._rows for c in (b, a)])

    @property
    def states(self) -> np.ndarray:
        """The two rows' lfilter states, concatenated."""
        return np.concatenate(self._states)

    @states.setter
    def states(self, z: np.ndarray) -> None:
        n = self.order
        self._states = [z[:n], z[n:]]

    def advance(self, voltage_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity) at each voltage sample."""
        from scipy.signal import lfilter

        outputs = []
        for k, (b, a) in enumerate(self._rows):
            y, self._states[k] = lfilter(b, a, voltage_v, zi=self._states[k])
            outputs.append(y)
        return outputs[0], outputs[1]


@lru_cache(maxsize=128)
def _filter_design(
    stack: StackParameters, sample_rate_hz: float
) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray]]:
    """(b, a) per output and the lfilter state for a unit constant input, memoised.

    Discretising costs ~60 ms (matrix exponential, ss2tf); a sweep or a design
    search builds thousands of plants with the same stack and rate.  Pure
    function of its (frozen) arguments; the arrays are read-only.
    """
    rows = _transfer_rows(stack.discrete(sample_rate_hz))
    states = [_unit_steady_state(b, a) for b, a in rows]
    for array in [*(x for row in rows for x in row), *states]:
        array.flags.writeable = False
    return rows, states


def _unit_steady_state(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """lfilter state of a filter that has seen the constant input 1 forever."""
    from scipy.signal import lfilter_zi

    n = max(len(a), len(b)) - 1
    if n == 0:
        return np.zeros(0)
    return lfilter_zi(b, a)
