"""``python -m firmware_sim``: the amplifier firmware and the world behind it, as a program.

Starts the firmware (tick loop on the chosen clock), the world (plant + camera)
and the endpoints, prints ONE JSON line on stdout::

    {"ready": true, "pid": 1234, "clock": "real",
     "endpoints": {"console_pty": "/dev/pts/7", "console_tcp": "socket://127.0.0.1:7230",
                   "sensor_tcp": "socket://127.0.0.1:40123", "camera_http": "http://127.0.0.1:8080"},
     "true": {"tau_pa": ..., "step_up_m": ..., "step_down_m": ..., "step_scatter": ..., ...}}

and runs until SIGINT/SIGTERM (then grounds every axis, closes the endpoints,
prints the tick statistics as one JSON line on stderr and exits 0).
Protocol reference: docs/anc300-protocol.md.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from types import FrameType

from feeder.errors import InputError
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.planar_plant import DEFAULT_LEVER_ARM_M
from feeder.protocol.anc300 import DEFAULT_PASSWORD, DIALECTS
from firmware_sim.canopen_node import serve_slcan_pty
from firmware_sim.clock import Clock, RealTimeClock, VirtualClock
from firmware_sim.console import ConsoleSession
from firmware_sim.firmware import (
    DEFAULT_DAC_BUFFER_S,
    DEFAULT_LOAD_CAPACITANCE_F,
    Axis,
    Firmware,
    FirmwareConfig,
)
from firmware_sim.transports import LineBroadcastServer, PtyConsole, TcpConsoleServer
from firmware_sim.world import PLANTS, CameraConfig, TrueStep, World, WorldConfig, parse_poses

REFERENCE_FREQUENCY_HZ = 100.0
VIRTUAL_TICKS_PER_YIELD = 10


def build_parser() -> argparse.ArgumentParser:
    amp = AmplifierLimits()
    parser = argparse.ArgumentParser(
        prog="python -m firmware_sim",
        description="Piezo amplifier firmware simulator (ANC300-compatible console) with "
                    "the stick-slip plant and a camera behind it.  Prints one JSON ready "
                    "line with the endpoints, runs until SIGINT/SIGTERM.")
    ends = parser.add_argument_group("endpoints (servers bind to 127.0.0.1 only)")
    ends.add_argument("--console", action="append", metavar="SPEC",
                      help="pty, or tcp:127.0.0.1:PORT (PORT 0 = any free port; the ANC300's "
                           "is 7230); repeatable; default: pty")
    ends.add_argument("--serial-login", action="store_true",
                      help="ask for the password on the pty too (TCP always asks)")
    ends.add_argument("--dialect", choices=DIALECTS, default="extended",
                      help="console verbs: anc300 = only a real ANC300's (every extension "
                           "verb gets its error reply; what the daemon starts), extended = "
                           "plus the test and diagnostic extensions (default)")
    ends.add_argument("--password", default=DEFAULT_PASSWORD,
                      help="console password (default %(default)s, as on real units)")
    ends.add_argument("--sensor", metavar="SPEC",
                      help="camera frame stream, tcp:127.0.0.1:PORT (JSON lines)")
    ends.add_argument("--camera-http", type=int, metavar="PORT",
                      help="microscope camera on http://127.0.0.1:PORT (0 = any free port): "
                           "/video.mjpg, /frame.png, /truth.json (endpoint camera_http)")
    ends.add_argument("--camera-http-fps", type=float, default=10.0, help="its frame rate")
    ends.add_argument("--camera-pixel-size-m", type=float, default=1e-6, help="its pixel size")
    add_extra_front_end_arguments(ends)

    fw = parser.add_argument_group("firmware")
    fw.add_argument("--clock", choices=("real", "virtual"), default="real",
                    help="real: 1 tick per period of wall time; virtual: ticks back to back "
                         "(deterministic, uses a CPU core)")
    fw.add_argument("--axes", type=int, default=3, help="configured axes 1..N (of 7 slots)")
    fw.add_argument("--tick-hz", type=float, default=1000.0)
    fw.add_argument("--sample-rate-hz", type=float, default=100_000.0, help="DAC rate")
    fw.add_argument("--dac-buffer-s", type=float, default=DEFAULT_DAC_BUFFER_S,
                    help="how far the tick keeps the DAC buffer ahead: a tick this late "
                         "still does not starve the DAC (commands act at once regardless)")
    fw.add_argument("--watchdog-s", type=float, default=0.25,
                    help="a tick this late grounds every axis")
    fw.add_argument("--host-watchdog-s", type=float, default=0.0,
                    help="ground a moving axis after this long without a host command (0 = off)")
    fw.add_argument("--v-max", type=float, default=amp.v_max_v, help="output rail, V")
    fw.add_argument("--slew-v-per-s", type=float, default=amp.slew_rate_v_per_s)
    fw.add_argument("--current-a", type=float, default=amp.current_limit_a)
    fw.add_argument("--max-frequency-hz", type=float, default=amp.max_frequency_hz)
    fw.add_argument("--load-capacitance-f", type=float, default=DEFAULT_LOAD_CAPACITANCE_F,
                    help="stack capacitance the current limit is enforced for")

    world = parser.add_argument_group("world (the plant's true parameters)")
    world.add_argument("--part", default="300x300x50", help="LxWxT in µm")
    world.add_argument("--support", default="flat", help="flat or grooved")
    tau = world.add_mutually_exclusive_group()
    tau.add_argument("--tau-pa", type=float,
                     help="true shear strength τ (default: drawn in 22.18 ± 3.15 GPa from --seed)")
    tau.add_argument("--tau-offset", type=float,
                     help="true τ relative to the nominal 22.18 GPa, e.g. 0.15 = +15 %%")
    world.add_argument("--kinetic-ratio", type=float, default=0.8, help="F_k/F_s")
    world.add_argument("--scatter", type=float, default=0.02,
                       help="step-to-step relative scatter of the static friction")
    world.add_argument("--seed", type=int, default=0)
    world.add_argument("--plant-axis", type=int, default=1, help="axis wired to the stack")
    world.add_argument("--plant", choices=PLANTS, default="line",
                       help="line: one stack on --plant-axis (default); planar: axes 1-3 drive the "
                            "plate's x, y and θ, parts at --parts")
    world.add_argument("--parts", metavar="X,Y,PSI;...", default="0,0,0",
                       help="planar: the parts' poses in the plate frame (m, m, rad; origin at "
                            "the rotation centre O), ';' between parts (default %(default)s)")
    world.add_argument("--lever-arm-m", type=float, default=DEFAULT_LEVER_ARM_M,
                       help="planar: radius about O at which the θ stack turns the plate")
    world.add_argument("--camera-rate-hz", type=float, default=100.0)
    world.add_argument("--camera-noise-m", type=float, default=50e-9)
    world.add_argument("--camera-latency-s", type=float, default=0.010)
    return parser


def add_extra_front_end_arguments(group: argparse._ArgumentGroup) -> None:
    """Options of further front ends (e.g. CANopen) go here."""
    group.add_argument("--can", choices=("slcan-pty",),
                       help="CANopen: one node per axis behind an emulated SLCAN adapter on a "
                            "pty (endpoint slcan_pty; docs/canopen.md)")
    group.add_argument("--can-node-id-base", type=int, default=1,
                       help="CANopen node id of axis 1 (axis n gets base + n - 1)")


def _tcp_spec(spec: str, option: str) -> tuple[str, int]:
    """``tcp:HOST:PORT`` or ``socket://HOST:PORT`` → (host, port)."""
    rest = spec.removeprefix("socket://") if spec.startswith("socket://") else ""
    if not rest:
        kind, _, rest = spec.partition(":")
        rest = rest if kind == "tcp" else ""
    host, _, port = rest.rpartition(":")
    if not host or not port.isdigit():
        raise InputError(option, f"expected tcp:127.0.0.1:PORT or socket://127.0.0.1:PORT, "
                         f"got {spec!r}")
    return host, int(port)


def start_endpoints(args: argparse.Namespace, firmware: Firmware, world: World,
                    closers: list[Callable[[], None]]) -> dict[str, str]:
    """Start every endpoint asked for; returns the ready line's ``endpoints`` map."""
    endpoints: dict[str, str] = {}

    def true_step(axis: Axis) -> TrueStep | None:
        if axis.number != world.config.plant_axis:
            return None
        return world.true_step(axis)

    def session(password: str | None) -> Callable[[], ConsoleSession]:
        return lambda: ConsoleSession(firmware, password=password, true_step=true_step,
                                      dialect=args.dialect)

    for spec in args.console or ["pty"]:
        if spec == "pty":
            pty = PtyConsole(session(args.password if args.serial_login else None))
            closers.append(pty.close)
            endpoints["console_pty"] = pty.path
        else:
            host, port = _tcp_spec(spec, "--console")
            tcp = TcpConsoleServer(host, port, session(args.password))
            closers.append(tcp.close)
            endpoints["console_tcp"] = tcp.url

    if args.sensor:
        host, port = _tcp_spec(args.sensor, "--sensor")
        camera = LineBroadcastServer(host, port)
        closers.append(camera.close)
        world.publish = camera.publish
        endpoints["sensor_tcp"] = camera.url

    if args.camera_http is not None:
        from firmware_sim.camera_http import serve_world_camera  # OpenCV: the optional vision extra

        http = serve_world_camera(world, args.camera_http, args.camera_http_fps, args.camera_pixel_size_m,
                                  args.camera_latency_s)
        closers.append(http.close)
        endpoints["camera_http"] = http.url

    start_extra_front_ends(args, firmware, closers, endpoints)
    return endpoints


def start_extra_front_ends(args: argparse.Namespace, firmware: Firmware,
                           closers: list[Callable[[], None]], endpoints: dict[str, str]) -> None:
    """Further front ends (e.g. CANopen) start here, calling the same firmware API."""
    if args.can == "slcan-pty":
        endpoints["slcan_pty"], close_can = serve_slcan_pty(firmware, args.can_node_id_base)
        closers.append(close_can)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        amplifier = AmplifierLimits(v_max_v=args.v_max, slew_rate_v_per_s=args.slew_v_per_s,
                                    current_limit_a=args.current_a,
                                    max_frequency_hz=args.max_frequency_hz)
        config = FirmwareConfig(axes=args.axes, tick_hz=args.tick_hz,
                                sample_rate_hz=args.sample_rate_hz,
                                dac_buffer_s=args.dac_buffer_s, watchdog_s=args.watchdog_s,
                                host_watchdog_s=args.host_watchdog_s, amplifier=amplifier,
                                load_capacitance_f=args.load_capacitance_f)
        firmware = Firmware(config)
        world = World(WorldConfig(
            part=args.part, support=args.support, tau_pa=args.tau_pa, tau_offset=args.tau_offset,
            kinetic_ratio=args.kinetic_ratio, scatter=args.scatter, seed=args.seed,
            plant_axis=args.plant_axis, plant=args.plant, poses=parse_poses(args.parts),
            lever_arm_m=args.lever_arm_m,
            camera=CameraConfig(args.camera_rate_hz, args.camera_noise_m,
                                args.camera_latency_s)), config)
        firmware.axis(args.plant_axis)
    except (InputError, ValueError) as exc:
        print(f"firmware_sim: error: {exc}", file=sys.stderr)
        return 2
    world.attach(firmware)
    reference = firmware.axis(args.plant_axis)
    reference.set_amplitude(amplifier.max_amplitude_vpp)
    step = world.true_step(reference)
    reference.set_amplitude(0.0)

    stop = threading.Event()

    def on_signal(_signum: int, _frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    closers: list[Callable[[], None]] = []
    try:
        endpoints = start_endpoints(args, firmware, world, closers)
    except (InputError, ValueError, OSError) as exc:
        print(f"firmware_sim: error: {exc}", file=sys.stderr)
        return 2
    true = {**world.describe(),
            "step_up_m": step.up_m, "step_down_m": step.down_m, "step_scatter": step.scatter,
            "step_reference": {"frequency_hz": REFERENCE_FREQUENCY_HZ,
                               "amplitude_v": amplifier.max_amplitude_vpp,
                               "flyback_shape": "current-limited"}}
    print(json.dumps({"ready": True, "pid": os.getpid(), "clock": args.clock,
                      "endpoints": endpoints, "true": true}), flush=True)
    clock: Clock = RealTimeClock() if args.clock == "real" else VirtualClock()
    try:
        if clock.realtime:
            firmware.run(clock, stop)
        else:  # back to back, but let the front ends' threads in now and then
            while not stop.is_set():
                firmware.run(clock, stop, max_ticks=VIRTUAL_TICKS_PER_YIELD)
                time.sleep(0)
    finally:
        firmware.shutdown()
        for close in reversed(closers):
            close()
        print(json.dumps({"stopped": True, "tick": firmware.tick_summary()}), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
