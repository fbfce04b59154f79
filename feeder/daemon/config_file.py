"""The daemon's configuration file (TOML): read, checked key by key, into :class:`.config.DaemonConfig`.

Every section and key is optional; what is missing takes the default below.
An unknown section or key is refused, naming the nearest known one; a number outside
:data:`.config_fields.RANGES` is refused, not clipped.
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
baudrate = 38400              # serial port rate, bit/s (the ANC300's; USB CDC-ACM ignores it)
[amplifier.limits]            # narrows the model's rating (AmplifierLimits); never beyond it
v_max_v = 120.0
current_limit_a = 0.55
max_frequency_hz = 2000.0
[amplifier.can]               # python-can keyword arguments + node id (+ eds, heartbeat_s, supervise_host,
interface = "slcan"           # host_id); a CAN drive (can.channel) needs model or [amplifier.limits]
channel = "/dev/ttyACM0"
bitrate = 500000              # required by adapters that take the rate from the host (slcan, pcan, ...)
node_id = 1
host_id = 127                 # the node id the daemon beats as (supervise_host), 1–127
eds = "feeder_amplifier.eds"  # the nodes' EDS: axes per node (feeder_amplifier_3axis.eds: 3), or a path

[sensor]
address = "socket://127.0.0.1:7240"   # pyserial URL syntax, as for the amplifier
timeout_s = 1.0

[simulator]                   # only when the daemon starts firmware_sim itself
args = []                     # extra command-line arguments for firmware_sim

[part]
size = "300x300x50"           # µm
support = "flat"
surface = "surface.toml"      # optional, relative to this file's folder; default: the paper's surface
tau_pa = 22.18e9              # optional; default: the contact model's τ

[stack]                       # the piezo stacks and plate (StackParameters; the waveforms are planned
gain_m_per_v = 0.07e-6        # for them): free stroke per volt; the capacitance sets the current-
capacitance_f = 1.0e-6        # limited flyback; default: firmware_sim's, with a warning on hardware
resonance_hz = 30.0e3         # loaded first axial resonance
damping_ratio = 0.1
output_resistance_ohm = 8.0   # the amplifier's output resistance into the capacitance

[control]
rate_hz = 100.0
tolerance_m = 1e-6
min_position_m = -5e-3        # travel in x (and min_y_m, max_y_m in y); a plane located by the
max_position_m = 5e-3         # camera: default what it sees of the whole part, beyond it refused
settle_s = 0.05
average_samples = 3

[state]
dir = "~/.local/state/feeder" # calibration, history, last position (SQLite); relative: to this file
socket = "/run/user/1000/feeder/feeder.sock"

[http]                        # the browser console (docs/console.md); off without [http] or --http
listen = "127.0.0.1:8470"     # HOST:PORT (port 0: any free one)
allow_remote = false          # true: allow a listen address other than loopback
origins = []                  # further Origin values allowed to change state (a reverse proxy's)
camera = "http://127.0.0.1:8080/video.mjpg"   # the live view's frames (open_camera spec)
moves_per_s = 2.0             # rate limit of move, jog and calibrate requests ...
move_burst = 5                # ... after a burst of this many
```
"""

from __future__ import annotations

import dataclasses
import difflib
from pathlib import Path
from typing import Any

from feeder.daemon.config import (
    DEFAULT_HTTP_LISTEN,
    DEFAULT_MODELS,
    DEFAULT_PART,
    TRANSPORTS,
    TRAVEL_KEYS,
    AmplifierConfig,
    CameraConfig,
    DaemonConfig,
    HttpConfig,
    PlateConfig,
)
from feeder.daemon.config_fields import (
    check_keys,
    expanded_path,
    flag,
    integer,
    number,
    string,
    subtable,
)
from feeder.daemon.control_loop import LoopSettings
from feeder.errors import InputError, shown
from feeder.files import read_toml
from feeder.parts import Part, Support
from feeder.plant.amplifier import AmplifierLimits, amplifier_model, within_rating
from feeder.plant.stack import StackParameters
from feeder.plate_axes import AXES, DEFAULT_AXIS_MAP, MAX_AXIS, amplifier_node
from feeder.pose import part_poses

SECTIONS: dict[str, frozenset[str]] = {
    "amplifier": frozenset(
        {"transport", "model", "port", "axis", "timeout_s", "password", "baudrate", "limits", "can"}
    ),
    "sensor": frozenset({"address", "timeout_s"}),
    "simulator": frozenset({"args"}),
    "part": frozenset({"size", "support", "surface", "tau_pa"}),
    "control": frozenset(f.name for f in dataclasses.fields(LoopSettings)),
    "state": frozenset({"dir", "socket"}),
    "http": frozenset({"listen", "allow_remote", "origins", "camera", "moves_per_s", "move_burst"}),
    "plate": frozenset({"axes", "axis_map", "lever_arm_m", "parts"}),
    "camera": frozenset({"address", "timeout_s", "pixel_size_m", "width_px", "height_px", "fps", "aligned"}),
    "stack": frozenset(f.name for f in dataclasses.fields(StackParameters)),
}
"""The schema's sections and their keys (``[amplifier.limits]``: AmplifierLimits' fields;
``[amplifier.can]``: python-can keyword arguments plus :data:`CAN_DRIVER_KEYS`)."""

CAN_DRIVER_KEYS = frozenset({"node_id", "heartbeat_s", "eds", "supervise_host", "host_id"})
"""``[amplifier.can]`` keys that are the CANopen driver's, not python-can's."""

CAN_BITRATE_KEYS = ("bitrate", "btr", "timing")
"""python-can's keywords that set an adapter's bit rate (``btr``: a register value; ``timing``)."""

CAN_HOST_SETS_BITRATE = frozenset(
    {"slcan", "pcan", "kvaser", "ixxat", "vector", "seeedstudio", "robotell", "canalystii", "gs_usb"}
)
"""python-can interfaces whose adapter takes its bit rate from the host when it opens: without
one python-can sends none (slcan: no ``S`` command) or its own default, and the adapter joins the
bus at whatever rate it last had, flooding a live bus with error frames.  ``socketcan`` (the rate
is the kernel's, ``ip link set can0 type can bitrate ...``) and ``virtual`` need none."""


def _plate(table: dict[str, Any], where: str) -> PlateConfig:
    """``[plate]``: axes (any of x, y, theta; x first), axis map, lever arm, simulated parts."""
    axes = table.get("axes", ["x"])
    if not (isinstance(axes, list) and axes and all(a in AXES for a in axes) and len(set(axes)) == len(axes)):
        raise InputError(where, f"plate.axes must be a list of distinct axes among {', '.join(AXES)}")
    if axes[0] != "x":
        raise InputError(where, "plate.axes must start with x (the axis one-axis moves address)")
    axis_map = table.get("axis_map", dict(DEFAULT_AXIS_MAP))
    if not isinstance(axis_map, dict):
        raise InputError(where, "plate.axis_map must be a table, e.g. { x = 1, y = 2, theta = 3 }")
    check_keys(axis_map, set(AXES), where, "plate.axis_map.")
    numbers = {str(k): integer(axis_map, k, where, 1, "plate.axis_map.") for k in axis_map}
    for name, axis in numbers.items():
        if axis > MAX_AXIS:
            raise InputError(where, f"plate.axis_map.{name} = {axis} is outside [1, {MAX_AXIS}]")
    mapped = {**DEFAULT_AXIS_MAP, **numbers}
    if len({mapped[a] for a in axes}) != len(axes):
        raise InputError(where, "plate.axis_map gives two axes the same number")
    parts_text = table.get("parts", "0,0,0")
    if not isinstance(parts_text, str):
        raise InputError(where, "plate.parts must be a string X,Y,PSI;X,Y,PSI (m, m, rad)")
    try:
        parts = part_poses(parts_text, "plate.parts")
    except InputError as err:
        raise InputError(where, f"plate.parts: {err.message}") from None
    return PlateConfig(
        axes=tuple(axes),
        axis_map=mapped,
        lever_arm_m=number(
            table, "lever_arm_m", where, PlateConfig.lever_arm_m, positive=True, section="plate."
        ),
        parts=parts,
        parts_given="parts" in table,
    )


def _eds(value: Any, where: str, folder: Path) -> str:
    """``amplifier.can.eds``: a packaged EDS's name, or the path of an EDS this driver can read
    (relative to the configuration's ``folder``); returns the name or the absolute path."""
    from feeder.protocol.eds import PACKAGED_EDS, object_dictionary  # canopen only when CAN is used

    if not isinstance(value, str):
        raise InputError(where, f"amplifier.can.eds must be a string (an EDS name or path), got {value!r}")
    eds = value if value in PACKAGED_EDS else str(folder / Path(value).expanduser())
    try:
        object_dictionary(1, eds, "amplifier.can.eds")
    except InputError as err:
        raise InputError(where, str(err)) from None
    return eds


def load_config(path: Path | None) -> DaemonConfig:
    """Read the TOML file at ``path`` (None → the embedded default)."""
    if path is None:
        return DaemonConfig()
    where = str(path)
    doc = read_toml(path)
    for name in doc:
        if name not in SECTIONS:
            near = difflib.get_close_matches(str(name), sorted(SECTIONS), n=1)
            hint = f"; did you mean [{near[0]}]?" if near else f"; known: {', '.join(SECTIONS)}"
            raise InputError(where, f"unknown section [{name}]{hint}")
        check_keys(subtable(doc, name, where), SECTIONS[name], where, f"{name}.")

    amp = subtable(doc, "amplifier", where)
    transport = string(amp, "transport", where, "serial", "amplifier.")
    if transport not in TRANSPORTS:
        raise InputError(where, f"amplifier.transport must be one of {', '.join(TRANSPORTS)}")
    can = subtable(amp, "can", where, "amplifier.")
    axis = integer(amp, "axis", where, 1, "amplifier.")
    if "node_id" in can:
        integer(can, "node_id", where, 1, "amplifier.can.")
    if "heartbeat_s" in can:
        number(can, "heartbeat_s", where, 0.25, positive=True, section="amplifier.can.")
    if "host_id" in can:
        integer(can, "host_id", where, 127, "amplifier.can.")
    if "eds" in can:
        can["eds"] = _eds(can["eds"], where, path.parent.absolute())
    supervise = can.get("supervise_host", True)
    if not isinstance(supervise, bool):
        raise InputError(where, f"amplifier.can.supervise_host must be true or false, got {supervise!r}")
    if set(can) - CAN_DRIVER_KEYS and "channel" not in can:
        # python-can keywords without the adapter: a misspelt channel must never fall back
        # to the simulator
        near = difflib.get_close_matches("channel", [str(k) for k in can], n=1)
        raise InputError(
            where,
            "amplifier.can names a bus but no channel"
            + (f" (is {near[0]!r} meant to be 'channel'?)" if near else ""),
        )
    interface = can.get("interface")
    if (
        "channel" in can
        and interface in CAN_HOST_SETS_BITRATE
        and not any(k in can for k in CAN_BITRATE_KEYS)
    ):
        raise InputError(
            where,
            f"amplifier.can.bitrate: a {interface} adapter takes the bus's bit rate from the host; "
            "set bitrate (e.g. 500000), or btr or timing",
        )
    limits_t = subtable(amp, "limits", where, "amplifier.")
    if transport == "can" and "channel" in can and "model" not in amp and not limits_t:
        # a CAN drive is hardware of unknown rating: only the simulator may default to its own
        raise InputError(
            where, "amplifier.model: a CAN drive needs its rating: model = ... or [amplifier.limits]"
        )
    model = str(string(amp, "model", where, DEFAULT_MODELS[str(transport)], "amplifier."))
    try:
        rating = amplifier_model(model)
    except InputError as err:
        raise InputError(where, f"amplifier.model: {err.message}") from None
    check_keys(limits_t, {f.name for f in dataclasses.fields(AmplifierLimits)}, where, "amplifier.limits.")
    for key in limits_t:
        number(limits_t, key, where, 0.0, section="amplifier.limits.")
    try:
        limits = dataclasses.replace(rating, **{k: float(v) for k, v in limits_t.items()})
        within_rating(limits, rating, model)
    except InputError as err:
        raise InputError(where, f"amplifier.limits.{err.field}: {err.message}") from None
    amplifier = AmplifierConfig(
        transport=str(transport),
        model=model,
        port=string(amp, "port", where, None, "amplifier."),
        axis=axis,
        timeout_s=number(amp, "timeout_s", where, 1.0, positive=True, section="amplifier."),
        password=str(string(amp, "password", where, "123456", "amplifier.", empty=True)),
        baudrate=integer(amp, "baudrate", where, AmplifierConfig.baudrate, "amplifier."),
        limits=limits,
        can=dict(can),
    )

    sensor = subtable(doc, "sensor", where)
    sensor_address = string(sensor, "address", where, None, "sensor.")
    if sensor_address is not None and not sensor_address.startswith("socket://"):
        raise InputError(
            where,
            f"sensor.address must be a socket://HOST:PORT URL (the "
            f"amplifier's address syntax), got {sensor_address!r}",
        )
    sim = subtable(doc, "simulator", where)
    sim_args = sim.get("args", [])
    if not (isinstance(sim_args, list) and all(isinstance(a, str) for a in sim_args)):
        raise InputError(where, "simulator.args must be a list of strings")

    part_t = subtable(doc, "part", where)
    size_text = str(string(part_t, "size", where, DEFAULT_PART, "part."))
    support_text = str(string(part_t, "support", where, "flat", "part."))
    try:
        part = Part.parse(size_text)
    except InputError as err:
        raise InputError(where, f"part.size: {err.message}") from None
    try:
        support = Support.parse(support_text)
    except InputError as err:
        raise InputError(where, f"part.support: {err.message}") from None
    surface_path = expanded_path(string(part_t, "surface", where, None, "part."), path.parent.absolute())
    if surface_path is not None and not surface_path.is_file():
        raise InputError(where, f"part.surface: {shown(str(surface_path))}: no such file")
    tau = part_t.get("tau_pa")
    tau_pa = None if tau is None else number(part_t, "tau_pa", where, 0.0, positive=True, section="part.")

    control = subtable(doc, "control", where)
    defaults = DaemonConfig().loop
    loop_fields: dict[str, Any] = {}
    for f in dataclasses.fields(LoopSettings):
        if f.name in control:
            default = getattr(defaults, f.name)
            if isinstance(default, int):
                loop_fields[f.name] = integer(control, f.name, where, default, "control.")
            else:
                loop_fields[f.name] = number(
                    control, f.name, where, default, positive=f.name not in TRAVEL_KEYS, section="control."
                )
    loop = dataclasses.replace(defaults, **loop_fields)
    plate = _plate(subtable(doc, "plate", where), where)
    if transport == "can":
        _check_node_ids(can, plate, where)
    camera_t = subtable(doc, "camera", where)
    cam = CameraConfig()
    camera = CameraConfig(
        address=string(camera_t, "address", where, None, "camera."),
        timeout_s=number(camera_t, "timeout_s", where, cam.timeout_s, positive=True, section="camera."),
        pixel_size_m=number(
            camera_t, "pixel_size_m", where, cam.pixel_size_m, positive=True, section="camera."
        ),
        width_px=integer(camera_t, "width_px", where, cam.width_px, "camera."),
        height_px=integer(camera_t, "height_px", where, cam.height_px, "camera."),
        fps=number(camera_t, "fps", where, cam.fps, positive=True, section="camera."),
        aligned=flag(camera_t, "aligned", where, "camera."),
    )
    if sensor_address is not None and camera.address is not None:
        raise InputError(
            where,
            "sensor.address and camera.address both name the sensor: keep one (camera.address: a "
            "camera the daemon locates parts in; sensor.address: a stream of positions)",
        )
    if sensor_address is None and (plate.planar or camera.address is not None):  # the camera locates
        loop = _camera_travel(loop, control, camera, part, where, in_y=plate.planar)
        if plate.planar and amplifier.simulated:  # the simulator places the parts
            _parts_in_view(plate, camera, part, where)
    if not loop.min_position_m < loop.max_position_m:
        raise InputError(where, "control.min_position_m must be below control.max_position_m")
    if not loop.min_y_m < loop.max_y_m:
        raise InputError(where, "control.min_y_m must be below control.max_y_m")

    state = subtable(doc, "state", where)
    base = DaemonConfig()
    folder = path.parent.absolute()  # relative paths are relative to the file's folder
    http = _http_config(subtable(doc, "http", where), where) if "http" in doc else None
    return DaemonConfig(
        amplifier=amplifier,
        sensor_address=sensor_address,
        sensor_timeout_s=number(sensor, "timeout_s", where, 1.0, positive=True, section="sensor."),
        simulator_args=tuple(sim_args),
        part=part,
        support=support,
        surface_path=surface_path,
        tau_pa=tau_pa,
        loop=loop,
        plate=plate,
        camera=camera,
        state_dir=expanded_path(string(state, "dir", where, None, "state."), folder) or base.state_dir,
        socket_path=expanded_path(string(state, "socket", where, None, "state."), folder) or base.socket_path,
        http=http,
        stack=_stack(subtable(doc, "stack", where), where) if "stack" in doc else None,
    )


def _stack(table: dict[str, Any], where: str) -> StackParameters:
    """``[stack]``: the fields of :class:`StackParameters` it gives, the others its defaults."""
    values = {
        key: number(table, key, where, 0.0, positive=key != "output_resistance_ohm", section="stack.")
        for key in table
    }
    return StackParameters(**values)


def _check_node_ids(can: dict[str, Any], plate: PlateConfig, where: str) -> None:
    """Refuse node ids beyond CANopen's 1..127 for the plate's axes, and an
    ``amplifier.can.host_id`` (default 127, when the host is supervised) that is one of the
    amplifier's node ids: the host's heartbeat would be that node's (COB-ID 0x700 + id)."""
    node_id = int(can.get("node_id", 1))
    last = node_id
    if plate.planar:
        per_node = 1
        if "eds" in can:
            from feeder.protocol.eds import axis_count, object_dictionary  # canopen only for CAN

            per_node = axis_count(object_dictionary(1, str(can["eds"])))
        last, _ = amplifier_node(node_id, max(plate.axis_map[a] for a in plate.axes), per_node)
    nodes = f"node {node_id}" if last == node_id else f"nodes {node_id}..{last}"
    if last > 127:
        raise InputError(
            where, f"amplifier.can.node_id = {node_id}: the plate's axes need {nodes}, beyond CANopen's 127"
        )
    host_id = int(can.get("host_id", 127))
    if can.get("supervise_host", True) and node_id <= host_id <= last:
        raise InputError(
            where, f"amplifier.can.host_id = {host_id} is the amplifier's (it uses {nodes}): pick another id"
        )


def _camera_travel(
    loop: LoopSettings, control: dict[str, Any], camera: CameraConfig, part: Part, where: str, in_y: bool
) -> LoopSettings:
    """The travel of parts located by the camera: what the camera sees of a whole part
    (:meth:`CameraConfig.travel_m`) where ``[control]`` sets none; a configured limit beyond it
    is refused, naming the key and the field's limits.  One axis (not ``in_y``): x only, the
    part's y being wherever it lies."""
    half_x, half_y = camera.travel_m(part)
    view = _view(camera, part)
    if half_x <= 0 or half_y <= 0:
        raise InputError(where, f"camera: the image is too small for the part: {view}")
    limits = {"min_position_m": -half_x, "max_position_m": half_x}
    if in_y:
        limits.update(min_y_m=-half_y, max_y_m=half_y)
    for key, limit in limits.items():
        value = getattr(loop, key)
        if key in control and abs(value) > abs(limit):
            raise InputError(where, f"control.{key} = {value:g} reaches beyond the camera's view: {view}")
    for key, limit in limits.items():
        if key not in control:
            loop = dataclasses.replace(loop, **{key: limit})  # type: ignore[arg-type]
    return loop


def _view(camera: CameraConfig, part: Part) -> str:
    """What the camera sees of a whole ``part`` (:meth:`CameraConfig.travel_m`), for a message."""
    half_x, half_y = camera.travel_m(part)
    return (
        f"the camera ({camera.width_px}×{camera.height_px} px at {camera.pixel_size_m:g} m/px) sees the "
        f"whole {part.label} part with its centre within x [{-half_x:.4g}, {half_x:.4g}] m, "
        f"y [{-half_y:.4g}, {half_y:.4g}] m"
    )


def _parts_in_view(plate: PlateConfig, camera: CameraConfig, part: Part, where: str) -> None:
    """Refuse a simulated part placed where the camera does not see it whole: the daemon could
    not locate it and stayed in fault (a part in view but outside a narrower travel is fine: it
    blocks no move)."""
    half_x, half_y = camera.travel_m(part)
    for k, (x, y, _) in enumerate(plate.parts, 1):
        if abs(x) > half_x or abs(y) > half_y:
            raise InputError(
                where,
                f"plate.parts: part {k} at ({x:g}, {y:g}) m is out of view, where the daemon cannot "
                f"locate it: {_view(camera, part)}",
            )


def _http_config(table: dict[str, Any], where: str) -> HttpConfig:
    """The ``[http]`` section (its presence turns the console on)."""
    allow_remote = flag(table, "allow_remote", where, "http.")
    origins = table.get("origins", [])
    if not (isinstance(origins, list) and all(isinstance(o, str) and "://" in o for o in origins)):
        raise InputError(where, "http.origins must be a list of origins such as 'https://console.lab'")
    http = HttpConfig(
        allow_remote=allow_remote,
        origins=tuple(o.rstrip("/") for o in origins),
        camera=string(table, "camera", where, None, "http."),
        moves_per_s=number(table, "moves_per_s", where, 2.0, positive=True, section="http."),
        move_burst=integer(table, "move_burst", where, 5, "http."),
    )
    listen = str(string(table, "listen", where, DEFAULT_HTTP_LISTEN, "http."))
    try:
        return http.listening_on(listen, "http.listen")
    except InputError as err:
        raise InputError(where, f"http.listen: {err.message}") from None
