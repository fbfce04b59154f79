"""The daemon's links to its hardware: amplifier (serial console or CANopen) and camera.

With no hardware named in the configuration, :func:`open_links` starts
``firmware_sim`` (a separate program, :mod:`feeder.daemon.launcher`) for the
configured part and amplifier rating, and points the same drivers at its
console pty (or slcan pty for CAN) and camera port.  Should that program die,
the next reconnect starts a new one and uses its fresh endpoints: the old pty
path is never reopened (another program may own it by then).  Configured
hardware is reopened at its configured address, with the service's backoff.
"""

from __future__ import annotations

import concurrent.futures
import logging
import threading
from pathlib import Path
from typing import Any

from feeder.daemon.config import SIM_TICK_WATCHDOG_S, DaemonConfig, uses_camera
from feeder.daemon.launcher import Simulator
from feeder.drivers.amplifier import Amplifier
from feeder.drivers.anc300 import Anc300Amplifier
from feeder.drivers.anc300_link import Anc300Link
from feeder.drivers.camera import StreamCamera
from feeder.drivers.sensor import PositionSensor
from feeder.errors import InputError
from feeder.vision.calibration import CameraCalibration

log = logging.getLogger(__name__)

SLCAN_BITRATE = 500_000
CAN_HEARTBEAT_S = 0.25
"""Node heartbeat period the daemon asks for: a few lost periods mark the node dead, so a
loaded host must not miss one (``[amplifier.can] heartbeat_s`` overrides it)."""
CAN_KEYS = ("node_id", "heartbeat_s", "eds", "supervise_host", "host_id")
"""``[amplifier.can]`` keys that are the driver's, not python-can's."""


class DriverLinks:
    """Opens (and re-opens, to reconnect) the configured amplifier driver and camera client."""

    def __init__(
        self,
        config: DaemonConfig,
        amplifier_address: str | dict[str, Any],
        sensor_address: str,
        simulator: Simulator | None = None,
        log_path: Path | None = None,
    ) -> None:
        self.config = config
        self.amplifier_address = amplifier_address
        self.sensor_address = sensor_address
        self.simulator = simulator
        self.log_path = log_path
        self.respawns = 0
        self._lock = threading.Lock()
        # PR_SET_PDEATHSIG fires when the *thread* that started the child ends: respawns run
        # on this one long-lived thread, never on a reconnect thread that is about to end
        self._spawner = concurrent.futures.ThreadPoolExecutor(1, "simulator-spawner")

    def _simulator_alive(self) -> None:
        """Start a new firmware_sim when ours died; take its endpoints."""
        with self._lock:
            if self.simulator is None or self.simulator.alive():
                return
            self.simulator.stop()
            log.warning("firmware_sim (pid %d) died; starting a new one", self.simulator.process.pid)
            sim = self._spawner.submit(
                Simulator, simulator_args(self.config), log_path=self.log_path
            ).result()
            try:
                self.amplifier_address, self.sensor_address = simulator_addresses(self.config, sim)
            except InputError:
                sim.stop()
                raise
            self.simulator = sim
            self.respawns += 1

    def open_amplifier(self) -> Amplifier | dict[str, Amplifier]:
        """One axis' driver, or (a plate driven in the plane) one per axis on a shared link."""
        self._simulator_alive()
        amp = self.config.amplifier
        plate = self.config.plate
        axis_map = {a: plate.axis_map[a] for a in plate.axes}
        if isinstance(self.amplifier_address, dict):
            from feeder.drivers.canopen import CanopenAmplifier  # python-can only when used
            from feeder.drivers.canopen_link import DEFAULT_HOST_ID
            from feeder.protocol.eds import EDS_FILE, axis_count, object_dictionary

            node_id = int(self.amplifier_address.get("node_id", 1))
            heartbeat = float(self.amplifier_address.get("heartbeat_s", CAN_HEARTBEAT_S))
            eds = str(self.amplifier_address.get("eds", EDS_FILE))
            # the node grounds its moving axes when this daemon's heartbeat stops (a crash mid-move)
            supervise = bool(self.amplifier_address.get("supervise_host", True))
            host_id = int(self.amplifier_address.get("host_id", DEFAULT_HOST_ID))
            bus = {k: v for k, v in self.amplifier_address.items() if k not in CAN_KEYS}
            if plate.planar:
                from feeder.drivers.axes import open_canopen_axes

                return open_canopen_axes(bus, axis_map, node_id, eds, heartbeat_s=heartbeat,
                                         timeout_s=amp.timeout_s, supervise_host=supervise,
                                         host_id=host_id)  # fmt: skip
            od = object_dictionary(node_id, eds)  # one axis: amplifier.axis of a multi-axis node
            axis = amp.axis if axis_count(od) > 1 else 1
            return CanopenAmplifier(bus, node_id, od, heartbeat_s=heartbeat, timeout_s=amp.timeout_s,
                                    supervise_host=supervise, host_id=host_id, axis=axis)  # fmt: skip
        if plate.planar:
            from feeder.drivers.axes import open_anc300_axes

            link = Anc300Link(
                self.amplifier_address, password=amp.password, timeout_s=amp.timeout_s, baudrate=amp.baudrate
            )
            return open_anc300_axes(link, axis_map)
        return Anc300Amplifier.open(
            self.amplifier_address,
            amp.axis,
            timeout_s=amp.timeout_s,
            password=amp.password,
            baudrate=amp.baudrate,
        )

    def open_sensor(self, calibration: CameraCalibration | None = None) -> PositionSensor:
        """The JSON-lines stream when one is named, else the camera that locates the parts with
        ``calibration`` (the stored one; None: :meth:`configured_calibration`)."""
        self._simulator_alive()
        configured = self.configured_calibration()
        if configured is None:
            return StreamCamera(self.sensor_address, connect_timeout_s=self.config.sensor_timeout_s)
        from feeder.drivers.pose_camera import CameraPoseSensor, part_template
        from feeder.drivers.video_camera import open_camera

        part = self.config.part
        calibration = calibration or configured
        if self.config.plate.planar:  # the parts stay where the camera sees them whole
            outside = self.config.camera.travel_outside(calibration, part, self.config.loop)
            if outside is not None:
                raise InputError("travel", outside)
        return CameraPoseSensor(
            open_camera(
                self.sensor_address, size_px=(self.config.camera.width_px, self.config.camera.height_px)
            ),
            calibration,
            part_template(part.length_m, part.width_m, calibration),
            parts=len(self.config.plate.parts),  # the plate's parts, as the planner and status count them
        )

    def configured_calibration(self) -> CameraCalibration | None:
        """Where the daemon locates parts with a camera: the configured scale, the plate origin at
        the image centre, not turned, not mirrored (a stored calibration updates it)."""
        if not uses_camera(self.config):
            return None
        cam = self.config.camera
        return CameraCalibration(
            cam.pixel_size_m, origin_x_px=(cam.width_px - 1) / 2, origin_y_px=(cam.height_px - 1) / 2
        )

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "transport": self.config.amplifier.transport,
            "amplifier_model": self.config.amplifier.model,
            "amplifier": self.amplifier_address,
            "sensor": self.sensor_address,
            "simulated": self.simulator is not None,
        }
        if self.simulator is not None:
            out["simulator_pid"] = self.simulator.process.pid
            out["simulator_endpoints"] = self.simulator.endpoints
            out["simulator_true"] = self.simulator.ready.get("true")
            out["simulator_respawns"] = self.respawns
        return out

    def close(self) -> None:
        """Stop firmware_sim if this daemon started it."""
        if self.simulator is not None:
            self.simulator.stop()
        self._spawner.shutdown(wait=False)


def simulator_args(config: DaemonConfig) -> list[str]:
    """firmware_sim's command line for this configuration (its world = our part)."""
    limits = config.amplifier.limits
    args = [
        "--console",
        "pty",
        "--dialect",
        "anc300",
        "--part",
        config.part.label,
        "--support",
        config.support.kind,
        "--v-max",
        repr(limits.v_max_v),
        "--current-a",
        repr(limits.current_limit_a),
        "--slew-v-per-s",
        repr(limits.slew_rate_v_per_s),
        "--max-frequency-hz",
        repr(limits.max_frequency_hz),
    ]
    if config.stack is not None:  # the simulated rig has the stacks the configuration states
        stack = config.stack
        args += [
            "--load-capacitance-f",
            repr(stack.capacitance_f),
            "--stack-gain-m-per-v",
            repr(stack.gain_m_per_v),
            "--stack-resonance-hz",
            repr(stack.resonance_hz),
            "--stack-damping-ratio",
            repr(stack.damping_ratio),
            "--stack-output-resistance-ohm",
            repr(stack.output_resistance_ohm),
        ]
    # a loaded machine stalls the simulator's process, not a firmware: its tick watchdog is
    # relaxed (SIM_TICK_WATCHDOG_S); the planar plant's slips also share the firmware's tick
    args += ["--watchdog-s", repr(SIM_TICK_WATCHDOG_S)]
    if not config.plate.planar:  # the line's position stream; the plane's camera sees the parts
        args += ["--sensor", "tcp:127.0.0.1:0"]
    if config.amplifier.transport == "can":
        args += ["--can", "slcan-pty"]
        if "eds" in config.amplifier.can:  # the simulated nodes have the configured axes per node
            args += ["--can-eds", str(config.amplifier.can["eds"])]
    plate, cam = config.plate, config.camera
    if plate.planar:
        parts = ";".join(",".join(repr(v) for v in pose) for pose in plate.parts)
        args += [
            "--plant",
            "planar",
            f"--parts={parts}",
            "--lever-arm-m",
            repr(plate.lever_arm_m),
            "--camera-http",
            "0",
            "--camera-http-fps",
            repr(cam.fps),
            "--camera-pixel-size-m",
            repr(cam.pixel_size_m),
            "--camera-width-px",
            str(cam.width_px),
            "--camera-height-px",
            str(cam.height_px),
        ]
    return [*args, *config.simulator_args]


def spawn_simulator(config: DaemonConfig) -> Simulator | None:
    """firmware_sim started for ``config`` (not yet ready: it loads while the daemon imports and
    plans), or None when the configuration names hardware."""
    if hardware_sensor(config) is not None:
        return None
    config.state_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
    return Simulator(simulator_args(config), log_path=config.simulator_log_path, timeout_s=None)


def open_links(config: DaemonConfig, simulator: Simulator | None = None) -> DriverLinks:
    """The links for ``config``; starts firmware_sim when no hardware is named (or takes the
    one :func:`spawn_simulator` started)."""
    amp = config.amplifier
    sensor = hardware_sensor(config)
    if sensor is not None:
        address: str | dict[str, Any] = dict(amp.can) if amp.transport == "can" else str(amp.port)
        return DriverLinks(config, address, sensor)
    sim = simulator or spawn_simulator(config)
    assert sim is not None
    try:
        sim.wait_ready()
        address, sensor = simulator_addresses(config, sim)
    except InputError:
        sim.stop()
        raise
    return DriverLinks(config, address, sensor, sim, config.simulator_log_path)


def hardware_sensor(config: DaemonConfig, where: str = "config") -> str | None:
    """The sensor's address when ``config`` names hardware, None for the simulator;
    :class:`~feeder.errors.InputError` (naming ``where``, the file) unless it names both the
    amplifier and the sensor or neither."""
    amp = config.amplifier
    sensor = config.sensor_address or config.camera.address
    if amp.simulated != (sensor is None):
        raise InputError(
            where,
            "name both the amplifier (port or can.channel) and the sensor (camera.address, or "
            "sensor.address for a position stream) for hardware, or neither for the simulator",
        )
    return sensor


def simulator_addresses(config: DaemonConfig, sim: Simulator) -> tuple[str | dict[str, Any], str]:
    """The amplifier address (pty path, or python-can arguments) and the camera URL of a
    started firmware_sim, from its ready line."""
    amp = config.amplifier
    ends = sim.endpoints
    try:
        if amp.transport == "can":
            address: str | dict[str, Any] = {
                "interface": "slcan",
                "channel": ends["slcan_pty"],
                "bitrate": SLCAN_BITRATE,
                "sleep_after_open": 0,
                "node_id": int(amp.can.get("node_id", 1)),
                "heartbeat_s": float(amp.can.get("heartbeat_s", CAN_HEARTBEAT_S)),
                **({"eds": str(amp.can["eds"])} if "eds" in amp.can else {}),
            }
        else:
            address = ends["console_pty"]
        if config.plate.planar:
            return address, f"{ends['camera_http']}/video.mjpg"
        return address, ends["sensor_tcp"]
    except KeyError as err:
        raise InputError("firmware_sim", f"its ready line lacks the endpoint {err}") from None
