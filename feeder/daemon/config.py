"""The daemon's configuration (TOML), with an embedded default that needs no hardware.

Every section and key is optional; what is missing takes the default below.
With no ``amplifier.port`` (serial) or ``amplifier.can.channel`` (CAN) and no
``sensor.address``, the daemon starts ``python -m firmware_sim`` itself and
drives it exactly as it would real hardware.

```toml
[amplifier]
transport = "serial"          # "serial" (ANC300 console) or "can" (CANopen)
model = "anc300"              # the rating the planner plans within: "anc300" (0–150 V,
                              # ≤ 10 kHz; default for serial) or "firmware_sim" (200 V; CAN)
port = "/dev/ttyUSB0"         # serial device or pyserial URL (socket://, rfc2217://)
axis = 1
timeout_s = 1.0
password = "123456"           # sent when the console asks (TCP; ANC300 default)
[amplifier.limits]            # narrows the model's rating (AmplifierLimits); never beyond it
v_max_v = 120.0
current_limit_a = 0.55
max_frequency_hz = 2000.0
[amplifier.can]               # python-can keyword arguments + node id
interface = "slcan"
channel = "/dev/ttyACM0"
bitrate = 500000
node_id = 1

[sensor]
address = "socket://127.0.0.1:7240"   # pyserial URL syntax, as for the amplifier
timeout_s = 1.0

[simulator]                   # only when the daemon starts firmware_sim itself
args = []                     # extra command-line arguments for firmware_sim

[part]
size = "300x300x50"           # µm
support = "flat"
surface = "surface.toml"      # optional; default: the paper's surface
tau_pa = 22.18e9              # optional; default: the contact model's τ

[control]
rate_hz = 100.0
tolerance_m = 1e-6
min_position_m = -5e-3
max_position_m = 5e-3
settle_s = 0.05
average_samples = 3

[state]
dir = "~/.local/state/feeder" # calibration, history, last position (SQLite)
socket = "/run/user/1000/feeder/feeder.sock"
```
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from feeder.daemon.control_loop import LoopSettings
from feeder.errors import InputError
from feeder.files import read_toml
from feeder.parts import Part, Support
from feeder.plant.amplifier import (
    AMPLIFIER_MODELS,
    AmplifierLimits,
    amplifier_model,
    within_rating,
)

TRANSPORTS = ("serial", "can")
DEFAULT_MODELS = {"serial": "anc300", "can": "firmware_sim"}
"""The amplifier model a transport gets when the configuration names none."""
DEFAULT_PART = "300x300x50"


def default_state_dir() -> Path:
    """``$XDG_STATE_HOME/feeder``, else ``~/.local/state/feeder``."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "feeder"


def default_socket_path() -> Path:
    """``$XDG_RUNTIME_DIR/feeder/feeder.sock``, else ``/tmp/feeder-<uid>/feeder.sock``."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    base = Path(runtime) / "feeder" if runtime else Path("/tmp") / f"feeder-{os.getuid()}"
    return base / "feeder.sock"


@dataclass(frozen=True)
class AmplifierConfig:
    transport: str = "serial"
    model: str = "anc300"
    port: str | None = None
    axis: int = 1
    timeout_s: float = 1.0
    password: str = "123456"
    limits: AmplifierLimits = field(default_factory=lambda: AMPLIFIER_MODELS["anc300"])
    can: dict[str, Any] = field(default_factory=dict)

    @property
    def simulated(self) -> bool:
        """True when no hardware is named: the daemon starts firmware_sim."""
        if self.transport == "can":
            return "channel" not in self.can
        return self.port is None


@dataclass(frozen=True)
class DaemonConfig:
    amplifier: AmplifierConfig = field(default_factory=AmplifierConfig)
    sensor_address: str | None = None
    sensor_timeout_s: float = 1.0
    simulator_args: tuple[str, ...] = ()
    part: Part = field(default_factory=lambda: Part.parse(DEFAULT_PART))
    support: Support = field(default_factory=Support)
    surface_path: Path | None = None
    tau_pa: float | None = None
    loop: LoopSettings = field(
        default_factory=lambda: LoopSettings(min_position_m=-5e-3, max_position_m=5e-3))
    state_dir: Path = field(default_factory=default_state_dir)
    socket_path: Path = field(default_factory=default_socket_path)

    @property
    def database_path(self) -> Path:
        return self.state_dir / "feeder.sqlite"

    def with_transport(self, transport: str) -> DaemonConfig:
        """The same configuration over ``transport``; an embedded default also takes that
        transport's default amplifier model."""
        if transport not in TRANSPORTS:
            raise InputError("--transport", f"expected one of {', '.join(TRANSPORTS)}")
        amp = dataclasses.replace(self.amplifier, transport=transport)
        if self.amplifier == AmplifierConfig():
            model = DEFAULT_MODELS[transport]
            amp = dataclasses.replace(amp, model=model, limits=AMPLIFIER_MODELS[model])
        return dataclasses.replace(self, amplifier=amp)


def _table(doc: dict[str, Any], name: str, where: str) -> dict[str, Any]:
    value = doc.get(name, {})
    if not isinstance(value, dict):
        raise InputError(where, f"[{name}] must be a table")
    return value


def _number(table: dict[str, Any], key: str, where: str, default: float,
            positive: bool = False) -> float:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(where, f"{key} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise InputError(where, f"{key} must be positive, got {value!r}")
    return float(value)


def _string(table: dict[str, Any], key: str, where: str, default: str | None) -> str | None:
    value = table.get(key, default)
    if value is not None and not isinstance(value, str):
        raise InputError(where, f"{key} must be a string, got {value!r}")
    return value


def _path(value: str | None) -> Path | None:
    return None if value is None else Path(value).expanduser()


def load_config(path: Path | None) -> DaemonConfig:
    """Read the TOML file at ``path`` (None → the embedded default)."""
    if path is None:
        return DaemonConfig()
    where = str(path)
    doc = read_toml(path)
    known = {"amplifier", "sensor", "simulator", "part", "control", "state"}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise InputError(where, f"unknown section [{unknown[0]}]; known: {', '.join(sorted(known))}")

    amp = _table(doc, "amplifier", where)
    transport = _string(amp, "transport", where, "serial")
    if transport not in TRANSPORTS:
        raise InputError(where, f"amplifier.transport must be one of {', '.join(TRANSPORTS)}")
    can = _table(amp, "can", where)
    axis = amp.get("axis", 1)
    if not isinstance(axis, int) or isinstance(axis, bool) or axis < 1:
        raise InputError(where, f"amplifier.axis must be a positive integer, got {axis!r}")
    model = str(_string(amp, "model", where, DEFAULT_MODELS[str(transport)]))
    try:
        rating = amplifier_model(model)
    except InputError as err:
        raise InputError(where, f"amplifier.model: {err.message}") from None
    limits_t = _table(amp, "limits", where)
    known_limits = {f.name for f in dataclasses.fields(AmplifierLimits)}
    for key in limits_t:
        if key not in known_limits:
            raise InputError(where, f"unknown key amplifier.limits.{key}; known: "
                             f"{', '.join(sorted(known_limits))}")
        _number(limits_t, key, where, 0.0)
    try:
        limits = dataclasses.replace(rating, **{k: float(v) for k, v in limits_t.items()})
        within_rating(limits, rating, model)
    except InputError as err:
        raise InputError(where, f"amplifier.limits.{err.field}: {err.message}") from None
    amplifier = AmplifierConfig(
        transport=str(transport), model=model, port=_string(amp, "port", where, None), axis=axis,
        timeout_s=_number(amp, "timeout_s", where, 1.0, positive=True),
        password=str(_string(amp, "password", where, "123456")),
        limits=limits, can=dict(can),
    )

    sensor = _table(doc, "sensor", where)
    sensor_address = _string(sensor, "address", where, None)
    if sensor_address is not None and not sensor_address.startswith("socket://"):
        raise InputError(where, f"sensor.address must be a socket://HOST:PORT URL (the "
                         f"amplifier's address syntax), got {sensor_address!r}")
    sim = _table(doc, "simulator", where)
    sim_args = sim.get("args", [])
    if not (isinstance(sim_args, list) and all(isinstance(a, str) for a in sim_args)):
        raise InputError(where, "simulator.args must be a list of strings")

    part_t = _table(doc, "part", where)
    part = Part.parse(str(_string(part_t, "size", where, DEFAULT_PART)))
    support = Support.parse(str(_string(part_t, "support", where, "flat")))
    tau = part_t.get("tau_pa")
    tau_pa = None if tau is None else _number(part_t, "tau_pa", where, 0.0, positive=True)

    control = _table(doc, "control", where)
    defaults = DaemonConfig().loop
    loop_fields: dict[str, Any] = {}
    for f in dataclasses.fields(LoopSettings):
        if f.name in control:
            default = getattr(defaults, f.name)
            if isinstance(default, int):
                value = control[f.name]
                if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                    raise InputError(where, f"control.{f.name} must be a positive integer")
                loop_fields[f.name] = value
            else:
                loop_fields[f.name] = _number(control, f.name, where, default,
                                              positive="position" not in f.name)
    unknown_keys = sorted(set(control) - {f.name for f in dataclasses.fields(LoopSettings)})
    if unknown_keys:
        raise InputError(where, f"unknown key control.{unknown_keys[0]}")
    loop = dataclasses.replace(defaults, **loop_fields)
    if not loop.min_position_m < loop.max_position_m:
        raise InputError(where, "control.min_position_m must be below control.max_position_m")

    state = _table(doc, "state", where)
    base = DaemonConfig()
    return DaemonConfig(
        amplifier=amplifier,
        sensor_address=sensor_address,
        sensor_timeout_s=_number(sensor, "timeout_s", where, 1.0, positive=True),
        simulator_args=tuple(sim_args),
        part=part,
        support=support,
        surface_path=_path(_string(part_t, "surface", where, None)),
        tau_pa=tau_pa,
        loop=loop,
        state_dir=_path(_string(state, "dir", where, None)) or base.state_dir,
        socket_path=_path(_string(state, "socket", where, None)) or base.socket_path,
    )
