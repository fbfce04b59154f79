"""The daemon's configuration: what it drives and how (:class:`DaemonConfig`), with an embedded
default that needs no hardware, and the embedded planar world (:func:`embedded_plane`).

The file that sets it: :mod:`feeder.daemon.config_file`.  With no amplifier
port or CAN channel and no sensor address, the daemon starts ``python -m
firmware_sim`` itself and drives it exactly as it would real hardware.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from feeder.daemon.client_connection import default_socket_path
from feeder.daemon.control_loop import LoopSettings
from feeder.errors import InputError
from feeder.parts import Part, Support
from feeder.plant.amplifier import AMPLIFIER_MODELS, AmplifierLimits
from feeder.plant.stack import StackParameters
from feeder.plate_axes import AXES, DEFAULT_AXIS_MAP

if TYPE_CHECKING:
    from feeder.vision.calibration import CameraCalibration

TRANSPORTS = ("serial", "can")
TRAVEL_KEYS = frozenset({"min_position_m", "max_position_m", "min_y_m", "max_y_m"})
DEFAULT_MODELS = {"serial": "anc300", "can": "firmware_sim"}
"""The amplifier model a transport gets when the configuration names none.  ``can``'s is the
simulator's rating: a configuration naming a CAN drive (``[amplifier.can] channel``) must give
``[amplifier] model`` or ``[amplifier.limits]`` (:func:`feeder.daemon.config_file.load_config`)."""
DEFAULT_PART = "300x300x50"
DEFAULT_HTTP_LISTEN = "127.0.0.1:8470"


def default_state_dir() -> Path:
    """``$XDG_STATE_HOME/feeder``, else ``~/.local/state/feeder``."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "feeder"


@dataclass(frozen=True)
class AmplifierConfig:
    transport: str = "serial"
    model: str = "anc300"
    port: str | None = None
    axis: int = 1
    timeout_s: float = 1.0
    password: str = "123456"
    baudrate: int = 38400
    """Bit/s of a serial port (the ANC300's console: 38400; USB CDC-ACM ignores it)."""
    limits: AmplifierLimits = field(default_factory=lambda: AMPLIFIER_MODELS["anc300"])
    can: dict[str, Any] = field(default_factory=dict)

    @property
    def simulated(self) -> bool:
        """True when no hardware is named: the daemon starts firmware_sim."""
        if self.transport == "can":
            return "channel" not in self.can
        return self.port is None


@dataclass(frozen=True)
class HttpConfig:
    """The browser console's server (:mod:`feeder.web`).

    moves_per_s, move_burst: token bucket over move, jog and calibrate requests.
    camera: an :func:`~feeder.drivers.video_camera.open_camera` spec for the live view.
    """

    host: str = "127.0.0.1"
    port: int = 8470
    allow_remote: bool = False
    origins: tuple[str, ...] = ()
    camera: str | None = None
    moves_per_s: float = 2.0
    move_burst: int = 5

    def listening_on(self, listen: str, field: str) -> HttpConfig:
        """The same settings at ``listen`` (``HOST:PORT``, ``[::1]:PORT``); a host that is not
        loopback is refused unless ``allow_remote``."""
        host, sep, port_text = listen.rpartition(":")
        host = host.removeprefix("[").removesuffix("]")
        if not sep or not host or not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
            raise InputError(field, f"expected HOST:PORT (e.g. {DEFAULT_HTTP_LISTEN}), got {listen!r}")
        if not self.allow_remote and not is_loopback(host):
            raise InputError(
                field,
                f"{host} is not a loopback address; the console serves loopback only "
                "unless the configuration says [http] allow_remote = true",
            )
        return dataclasses.replace(self, host=host, port=int(port_text))


def is_loopback(host: str) -> bool:
    """``localhost`` or a loopback IP address (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True)
class PlateConfig:
    """The plate's axes and parts.

    axes: which axes the daemon drives (``("x",)``: one axis, today's feeder;
    ``("x", "y", "theta")``: the plane, parts brought to poses); axis_map: each
    axis' ANC300 axis number or CANopen node id; lever_arm_m: radius about O at
    which the θ stack drives the plate (simulator); parts: the parts on the plate,
    as their start poses (m, m, rad; plate frame): the simulator places them there;
    on hardware their number is how many the camera must locate; parts_given: the
    configuration names them (``--plane`` keeps them on a one-axis configuration).
    """

    axes: tuple[str, ...] = ("x",)
    axis_map: dict[str, int] = field(default_factory=lambda: dict(DEFAULT_AXIS_MAP))
    lever_arm_m: float = 1e-3
    parts: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 0.0),)
    parts_given: bool = False

    @property
    def planar(self) -> bool:
        return len(self.axes) > 1


VIEW_MARGIN_PX = 10
"""A part's outline stays this many pixels inside the image: the blob search refuses a blob that
touches the border of the image it shrinks up to 4× (:mod:`feeder.vision.locate`), and the edge
fits sample profiles reaching 10 px beyond each side (:mod:`feeder.vision.edges`)."""


@dataclass(frozen=True)
class CameraConfig:
    """The microscope camera the daemon locates parts with (a plate driven in the plane).

    address: what :func:`feeder.drivers.video_camera.open_camera` opens (an MJPEG
    URL, a device index, ``genicam:PRODUCER#SERIAL``); None with the simulator (its
    camera); pixel_size_m, width_px, height_px: the image's scale and size, used
    (plate origin at the image centre, axes along the image's) until ``feeder vision
    calibrate --save-state`` stores a measured calibration; fps: the simulated
    camera's frame rate.  The simulator's default, 2048 px at 2.7 µm/px, sees ±2.76 mm
    (a 300 µm part anywhere in the ±2.4 mm travel) with the part 111 px wide: angle error
    0.013° RMS against the simulator's truth (at 5 µm/px, 60 px: 0.058°, too coarse for a
    0.1° tolerance).  15 frames/s: a 2048 px JPEG (quality 90, with the sensor's noise) costs
    ~12 ms to encode and ~25 ms to decode on a quiet core (three times as much under load), so
    30 frames/s would take most of this 2-core machine; 15 keep the console's live view
    above 10 frames/s.
    """

    address: str | None = None
    timeout_s: float = 2.0
    pixel_size_m: float = 2.7e-6
    width_px: int = 2048
    height_px: int = 2048
    fps: float = 15.0
    aligned: bool = False
    """The configured calibration is this camera's: its image axes are the plate's (not turned,
    not mirrored), O at the image centre.  Without it a camera at ``address`` locates nothing for
    a move until ``feeder vision calibrate --save-state`` stored its measured calibration (a
    camera looking down on a plate sees it mirrored: y and θ would come out with the wrong sign)."""

    def uncalibrated(self) -> str | None:
        """Why moves must wait for a stored calibration, or None (the simulator's camera, whose
        geometry the daemon sets, or ``aligned``)."""
        if self.address is None or self.aligned:
            return None
        return (
            f"the camera {self.address} is not calibrated: the configuration assumes its image is "
            "neither turned nor mirrored against the plate; run `feeder vision calibrate-moves "
            "--stack-gain … --save-state` (or `feeder vision calibrate --x-move … --y-move … "
            "--save-state`; docs/daemon.md, Configuration), or set [camera] aligned = true if it is so"
        )

    def travel_m(self, part: Part) -> tuple[float, float]:
        """Half-widths (x, y; m) of the region about O where ``part``'s centre keeps the whole
        part, at any angle, in view: the image (O at its centre, axes along the image's, as
        configured) less the part's half-diagonal and :data:`VIEW_MARGIN_PX` pixels.  Negative:
        the image is too small for the part."""
        margin_m = 0.5 * math.hypot(part.length_m, part.width_m) + VIEW_MARGIN_PX * self.pixel_size_m
        return (
            0.5 * self.width_px * self.pixel_size_m - margin_m,
            0.5 * self.height_px * self.pixel_size_m - margin_m,
        )

    def travel_outside(self, calibration: CameraCalibration, part: Part, loop: LoopSettings) -> str | None:
        """Why ``loop``'s travel reaches beyond what the camera sees of a whole part when it
        locates with ``calibration`` (a stored one may be turned, mirrored, off centre, finer), or
        None: every travel corner's image keeps the part's half-diagonal and
        :data:`VIEW_MARGIN_PX` inside the image (the calibration is a similarity: the travel's
        rectangle maps to a parallelogram, whose corners decide)."""
        reach_px = 0.5 * math.hypot(part.length_m, part.width_m) / calibration.pixel_size_m + VIEW_MARGIN_PX
        bounds = [(reach_px - 0.5, size - 0.5 - reach_px) for size in (self.width_px, self.height_px)]
        o = calibration.to_image(0.0, 0.0)
        fits, worst = 1.0, None
        for x in (loop.min_position_m, loop.max_position_m):
            for y in (loop.min_y_m, loop.max_y_m):
                corner = calibration.to_image(x, y)
                for k in (0, 1):
                    lo, hi = bounds[k]
                    if not lo - 1e-6 <= corner[k] <= hi + 1e-6:
                        worst = worst or (x, y, corner)
                        edge = hi if corner[k] > hi else lo
                        fits = min(fits, max(0.0, (edge - o[k]) / (corner[k] - o[k])))
        if worst is None:
            return None
        x, y, (u, v) = worst
        turn = math.degrees(calibration.rotation_rad)
        seen = (
            f"{calibration.pixel_size_m * 1e6:.4g} µm/px, turned {turn:.1f}°"
            f"{', mirrored' if calibration.mirrored else ''}, O at ({o[0]:.0f}, {o[1]:.0f}) px"
        )
        return (
            f"the travel x [{loop.min_position_m:.4g}, {loop.max_position_m:.4g}] m, y [{loop.min_y_m:.4g}, "
            f"{loop.max_y_m:.4g}] m reaches beyond what the camera sees of a whole {part.label} part "
            f"({seen}): its corner ({x:.4g}, {y:.4g}) m is at ({u:.0f}, {v:.0f}) px in the "
            f"{self.width_px}×{self.height_px} px image; the travel scaled by {fits:.3f} about O fits "
            "([control] min_position_m, max_position_m, min_y_m, max_y_m)"
        )


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
        default_factory=lambda: LoopSettings(min_position_m=-5e-3, max_position_m=5e-3)
    )
    plate: PlateConfig = field(default_factory=PlateConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    state_dir: Path = field(default_factory=default_state_dir)
    socket_path: Path = field(default_factory=default_socket_path)
    http: HttpConfig | None = None
    """The browser console; None: off."""
    stack: StackParameters | None = None
    """The piezo stacks and plate (``[stack]``); None: not stated, firmware_sim's are assumed."""

    @property
    def planning_stack(self) -> StackParameters:
        """The stacks the waveforms are planned for: ``[stack]``'s, else firmware_sim's."""
        return self.stack or StackParameters()

    @property
    def stack_warning(self) -> str | None:
        """Why the waveforms may not suit the hardware (no ``[stack]`` on hardware), or None."""
        if self.stack is not None or self.amplifier.simulated:
            return None
        s = self.planning_stack
        return (
            f"no [stack] in the configuration: the waveforms are planned for firmware_sim's stacks "
            f"({s.gain_m_per_v * 1e6:g} µm/V, {s.capacitance_f * 1e6:g} µF, {s.resonance_hz / 1e3:g} kHz); "
            "the capacitance sets the current-limited flyback, so state yours"
        )

    @property
    def stack_gain_m_per_v(self) -> float | None:
        """The stacks' static gain (m/V) where it is known: ``[stack]``'s, or the simulator's
        (which is given ``[stack]`` too); None on hardware without ``[stack]``."""
        if self.stack is None and not self.amplifier.simulated:
            return None
        return self.planning_stack.gain_m_per_v

    @property
    def database_path(self) -> Path:
        return self.state_dir / "feeder.sqlite"

    @property
    def simulator_log_path(self) -> Path:
        """The embedded firmware_sim's stderr (appended)."""
        return self.state_dir / "firmware_sim.log"

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

    def with_state_dir(self, state_dir: Path | None) -> DaemonConfig:
        """The same configuration keeping its state in ``state_dir`` (``--state-dir``; None: as it is)."""
        return self if state_dir is None else dataclasses.replace(self, state_dir=state_dir)

    def with_simulator_args(self, extra: Sequence[str]) -> DaemonConfig:
        """The same configuration, the embedded firmware_sim given ``extra`` arguments too."""
        return dataclasses.replace(self, simulator_args=(*self.simulator_args, *extra))


PLANE_TRAVEL_M = 2.4e-3
"""The embedded plane's travel in x and y, ± (m): its camera (2048 px at 2.7 µm/px) sees a
300 µm part anywhere in it (:meth:`CameraConfig.travel_m`: ±2.53 mm), with room for a measured
calibration's error: one from plate moves ~0.3 % finer and O a few pixels off the centre is
stored (at ±2.5 mm, 1 % of margin, the console test's 2.695 µm/px, O 3 px off, was refused for the
travel in 1 of 4 runs)."""
PLANE_START_POSE = (0.8e-3, 0.4e-3, 0.2)
"""Where the embedded plane's part lies when the simulator starts (m, m, rad)."""
PLANE_SETTLE_S = 0.1
"""After a burst, wait at least this long before reading the part: the camera's frames arrive
(exposure, JPEG, HTTP, decoding, locating) 0.05–0.15 s after what they show, and the policy
waits 1.25 × the latency it sees when that is longer (:data:`~feeder.daemon.sensor_latency.LATENCY_MARGIN`).
At 0.2 s and two frames averaged the demo's five poses took 37 s; at 0.1 s and one frame, 23 s."""
PLANE_AVERAGE_FRAMES = 1
"""Frames averaged per measurement (15 frames/s; one frame's noise is ~0.015 µm as measured at
rest (``status`` ``sensor_noise_seen_m``) and ~0.01°, far below the default tolerances); two
must agree all the same (:data:`~feeder.daemon.burst_cycle.MIN_AGREEING`)."""
SIM_TICK_WATCHDOG_S = 2.0
"""The embedded simulator's tick watchdog (line and plane; firmware_sim's own default is 0.25 s)
and, in the plane, the loop's grace for a burst's end.  A loaded machine deschedules the
simulator's process, which is no stalled firmware: at 0.25 s a CI run's `feeder demo --line`
ended a move `fault` ("stepu: Axis in wrong mode", the watchdog having grounded the axis).  The
planar plant runs in the firmware's tick (its slowest 1 ms tick: ~1 ms for one axis, 5.3 ms
over 50 random drives of up to three axes; seconds before the near-miss fix), and a machine
loaded by a browser starting, the camera's encoding and decoding and the daemon delays it by
up to a second (a 1 s grace ended a move "did not finish the burst in time" once); the
simulated device's time waits for its world (``firmware_sim.firmware.WORLD_SHARE``), so a slow
plant stretches a burst in wall time; a real amplifier's tick never waits for physics.  The
simulated amplifier's link timeout is as long."""
PLANE_HEARTBEAT_S = 0.8
"""The simulated CANopen nodes' heartbeat in the plane, lost after 2.5 periods
(:data:`~feeder.drivers.canopen_link.HEARTBEAT_LOSS_PERIODS`): 2 s, as long as the tick watchdog
grants the planar plant's slowest tick (:data:`SIM_TICK_WATCHDOG_S`), which holds the simulator's
heartbeat back too (at 0.5 s, a node was taken for lost after 1.47 s on a loaded machine, and a
move ended ``fault``)."""


def embedded_plane(config: DaemonConfig) -> DaemonConfig:
    """``config`` on the embedded planar world (``feeder daemon --plane``, ``feeder demo``):
    three axes x, y, θ, travel ±2.4 mm in x and y, the simulator's camera, one part (unless
    ``config`` already places parts in the plane)."""
    loop = dataclasses.replace(
        config.loop,
        min_position_m=-PLANE_TRAVEL_M,
        max_position_m=PLANE_TRAVEL_M,
        min_y_m=-PLANE_TRAVEL_M,
        max_y_m=PLANE_TRAVEL_M,
        settle_s=PLANE_SETTLE_S,
        average_samples=PLANE_AVERAGE_FRAMES,
        burst_grace_s=SIM_TICK_WATCHDOG_S,
    )
    parts = config.plate.parts if config.plate.planar or config.plate.parts_given else (PLANE_START_POSE,)
    plate = dataclasses.replace(config.plate, axes=AXES, parts=parts)
    amplifier = config.amplifier
    if amplifier.simulated:  # the simulated plant's rare slow tick (SIM_TICK_WATCHDOG_S)
        can = {"heartbeat_s": PLANE_HEARTBEAT_S, **amplifier.can}
        amplifier = dataclasses.replace(amplifier, timeout_s=SIM_TICK_WATCHDOG_S, can=can)
    return dataclasses.replace(config, loop=loop, plate=plate, amplifier=amplifier)


def uses_camera(config: DaemonConfig) -> bool:
    """The daemon locates parts in a camera's frames: a plate in the plane, or one axis given
    ``camera.address`` (part 1's x), unless a position stream (``sensor.address``) is named."""
    return config.sensor_address is None and (config.plate.planar or config.camera.address is not None)
