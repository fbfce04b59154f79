"""The daemon's links to its hardware: amplifier (serial console or CANopen) and camera.

With no hardware named in the configuration, :func:`open_links` starts
``firmware_sim`` (a separate program, :mod:`feeder.daemon.launcher`) for the
configured part and amplifier rating, and points the same drivers at its
console pty (or slcan pty for CAN) and camera port.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from feeder.daemon.config import DaemonConfig
from feeder.daemon.launcher import Simulator
from feeder.drivers.amplifier import Amplifier
from feeder.drivers.anc300 import Anc300Amplifier
from feeder.drivers.camera import StreamCamera
from feeder.drivers.sensor import PositionSensor
from feeder.errors import InputError

SLCAN_BITRATE = 500_000
CAN_HEARTBEAT_S = 0.25
"""Node heartbeat period the daemon asks for: a few lost periods mark the node dead, so a
loaded host must not miss one (``[amplifier.can] heartbeat_s`` overrides it)."""


class DriverLinks:
    """Opens (and re-opens, to reconnect) the configured amplifier driver and camera client."""

    def __init__(self, config: DaemonConfig, amplifier_address: str | dict[str, Any],
                 sensor_address: str, simulator: Simulator | None = None) -> None:
        self.config = config
        self.amplifier_address = amplifier_address
        self.sensor_address = sensor_address
        self.simulator = simulator

    def open_amplifier(self) -> Amplifier:
        amp = self.config.amplifier
        if isinstance(self.amplifier_address, dict):
            from feeder.drivers.canopen import CanopenAmplifier  # python-can only when used

            node_id = int(self.amplifier_address.get("node_id", 1))
            heartbeat = float(self.amplifier_address.get("heartbeat_s", CAN_HEARTBEAT_S))
            bus = {k: v for k, v in self.amplifier_address.items()
                   if k not in ("node_id", "heartbeat_s")}
            return CanopenAmplifier(bus, node_id, heartbeat_s=heartbeat, timeout_s=amp.timeout_s)
        return Anc300Amplifier.open(self.amplifier_address, amp.axis, timeout_s=amp.timeout_s,
                                    password=amp.password)

    def open_sensor(self) -> PositionSensor:
        return StreamCamera(self.sensor_address, connect_timeout_s=self.config.sensor_timeout_s)

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "transport": self.config.amplifier.transport,
            "amplifier_model": self.config.amplifier.model,
            "amplifier": self.amplifier_address, "sensor": self.sensor_address,
            "simulated": self.simulator is not None,
        }
        if self.simulator is not None:
            out["simulator_pid"] = self.simulator.process.pid
            out["simulator_endpoints"] = self.simulator.endpoints
            out["simulator_true"] = self.simulator.ready.get("true")
        return out

    def close(self) -> None:
        """Stop firmware_sim if this daemon started it."""
        if self.simulator is not None:
            self.simulator.stop()


def simulator_args(config: DaemonConfig) -> list[str]:
    """firmware_sim's command line for this configuration (its world = our part)."""
    limits = config.amplifier.limits
    args = ["--console", "pty", "--dialect", "anc300", "--sensor", "tcp:127.0.0.1:0",
            "--part", config.part.label, "--support", config.support.kind,
            "--v-max", repr(limits.v_max_v), "--current-a", repr(limits.current_limit_a),
            "--slew-v-per-s", repr(limits.slew_rate_v_per_s),
            "--max-frequency-hz", repr(limits.max_frequency_hz)]
    if config.amplifier.transport == "can":
        args += ["--can", "slcan-pty"]
    return [*args, *config.simulator_args]


def open_links(config: DaemonConfig, log_path: Path | None = None) -> DriverLinks:
    """The links for ``config``; starts firmware_sim when no hardware is named."""
    amp = config.amplifier
    if amp.simulated != (config.sensor_address is None):
        raise InputError("config", "name both the amplifier (port or can.channel) and "
                         "sensor.address for hardware, or neither for the simulator")
    if not amp.simulated:
        assert config.sensor_address is not None
        address: str | dict[str, Any] = dict(amp.can) if amp.transport == "can" else str(amp.port)
        return DriverLinks(config, address, config.sensor_address)
    sim = Simulator(simulator_args(config), log_path=log_path)
    ends = sim.endpoints
    try:
        if amp.transport == "can":
            address = {"interface": "slcan", "channel": ends["slcan_pty"],
                       "bitrate": SLCAN_BITRATE, "sleep_after_open": 0,
                       "node_id": int(amp.can.get("node_id", 1)),
                       "heartbeat_s": float(amp.can.get("heartbeat_s", CAN_HEARTBEAT_S))}
        else:
            address = ends["console_pty"]
        sensor = ends["sensor_tcp"]
    except KeyError as err:
        sim.stop()
        raise InputError("firmware_sim", f"its ready line lacks the endpoint {err}") from None
    return DriverLinks(config, address, sensor, sim)
