"""``python -m firmware_sim``: the amplifier firmware and the world behind it, as a program.

Starts the firmware (tick loop on the chosen clock), the world (plant + camera)
and the endpoints, prints ONE JSON line on stdout::

    {"ready": true, "pid": 1234, "clock": "real",
     "endpoints": {"console_pty": "/dev/pts/7", "console_tcp": "socket://127.0.0.1:7230",
                   "sensor_tcp": "socket://127.0.0.1:40123", "camera_http": "http://127.0.0.1:8080"},
     "true": {"tau_pa": ..., "step_up_m": ..., "step_down_m": ..., "step_scatter": ..., ...}}

and runs until SIGINT/SIGTERM (then grounds every axis, closes the endpoints,
prints the tick statistics as one JSON line on stderr and exits 0; it is gone
within :data:`EXIT_DEADLINE_S` of the signal, orderly or not).  The tick loop
runs in its own thread; the main thread only waits for a signal on a self-pipe
(``signal.set_wakeup_fd``), so no signal handler ever takes a lock.  A signal
during start-up ends the program at once.  Every option is range-checked
(:mod:`firmware_sim.options`): bad input is one line on stderr naming the
option, exit code 2.
Protocol reference: docs/anc300-protocol.md.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable
from types import FrameType

from feeder.errors import InputError
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.stack import StackParameters
from feeder.pose import parse_poses
from feeder.protocol.eds import EDS_FILE, axis_count, object_dictionary
from firmware_sim.axis import Axis
from firmware_sim.can_wire import CanWire
from firmware_sim.canopen_node import CanopenNode
from firmware_sim.clock import Clock, RealTimeClock, VirtualClock
from firmware_sim.console import ConsoleSession
from firmware_sim.faults import FirmwareError
from firmware_sim.firmware import Firmware, FirmwareConfig
from firmware_sim.login_throttle import LoginThrottle
from firmware_sim.options import (
    REFERENCE_FREQUENCY_HZ,
    build_parser,
    check_can_layout,
    check_options,
    tcp_spec,
)
from firmware_sim.slcan import SlcanPty
from firmware_sim.transports import LineBroadcastServer, PtyConsole, SessionFactory, TcpConsoleServer
from firmware_sim.world import CameraConfig, TrueStep, World, WorldConfig

VIRTUAL_TICKS_PER_YIELD = 10
SHUTDOWN_SIGNALS = (signal.SIGINT, signal.SIGTERM)
STOP_JOIN_S = 0.3
"""How long the main thread waits for the tick thread to finish its tick."""
EXIT_DEADLINE_S = 0.7
"""After SIGINT/SIGTERM the process is gone within this long: if the orderly shutdown
overruns it (a stuck tick), SIGALRM ends the process (exit status 128 + 14)."""
INTERRUPT_LATENCY_S = 100e-6
"""Longest wait of an arriving frame's thread for the interpreter (``sys.setswitchinterval``;
Python's default of 5 ms would let a busy tick delay an SDO answer by milliseconds)."""


def start_endpoints(
    args: argparse.Namespace, firmware: Firmware, world: World, closers: list[Callable[[], None]]
) -> dict[str, str]:
    """Start every endpoint asked for; returns the ready line's ``endpoints`` map."""
    endpoints: dict[str, str] = {}

    def true_step(axis: Axis) -> TrueStep | None:
        if axis.number != world.config.plant_axis:
            return None
        return world.true_step(axis)

    throttle = LoginThrottle()  # one per program: a source's tries are paced on every port

    def session(password: str | None) -> SessionFactory:
        return lambda source: ConsoleSession(
            firmware,
            password=password,
            true_step=true_step,
            dialect=args.dialect,
            throttle=throttle,
            source=source,
        )

    for spec in args.console or ["pty"]:
        if spec == "pty":
            pty = PtyConsole(session(args.password if args.serial_login else None))
            closers.append(pty.close)
            endpoints["console_pty"] = pty.path
        else:
            host, port = tcp_spec(spec, "--console")
            tcp = TcpConsoleServer(host, port, session(args.password))
            closers.append(tcp.close)
            endpoints["console_tcp"] = tcp.url

    if args.sensor:
        host, port = tcp_spec(args.sensor, "--sensor")
        camera = LineBroadcastServer(host, port)
        closers.append(camera.close)
        world.publish = camera.publish
        endpoints["sensor_tcp"] = camera.url

    if args.camera_http is not None:
        from firmware_sim.camera_http import serve_world_camera  # OpenCV: the optional vision extra
        from firmware_sim.camera_render import CameraModel

        http = serve_world_camera(
            world,
            args.camera_http,
            args.camera_http_fps,
            args.camera_pixel_size_m,
            args.camera_latency_s,
            CameraModel(width_px=args.camera_width_px, height_px=args.camera_height_px),
            rotation_rad=args.camera_rotation_rad,
            mirrored=args.camera_mirrored,
        )
        closers.append(http.close)
        endpoints["camera_http"] = http.url

    start_extra_front_ends(args, firmware, closers, endpoints)
    return endpoints


def start_extra_front_ends(
    args: argparse.Namespace, firmware: Firmware, closers: list[Callable[[], None]], endpoints: dict[str, str]
) -> None:
    """Further front ends (e.g. CANopen) start here, calling the same firmware API."""
    if args.can == "slcan-pty":
        endpoints["slcan_pty"], close_can = serve_slcan_pty(firmware, args.can_node_id_base, args.can_eds)
        closers.append(close_can)


def serve_slcan_pty(
    firmware: Firmware, node_id_base: int = 1, eds: str = EDS_FILE
) -> tuple[str, Callable[[], None]]:
    """Every configured axis behind an emulated SLCAN adapter on one :class:`CanWire`, as
    nodes of the EDS ``eds``: with A axes per node, node ``node_id_base`` + k serves axes
    k·A + 1 .. k·A + A; returns the pty path and a function that stops it all.

    Sets the interpreter's switch interval to :data:`INTERRUPT_LATENCY_S`: the
    thread a frame arrives in then gets the interpreter from the busy tick
    thread within that time, as an interrupt preempts a firmware's main loop.
    """
    per_node = axis_count(object_dictionary(node_id_base, eds, "--can-eds"))
    numbers = firmware.axis_numbers
    check_can_layout(len(numbers), per_node, node_id_base, eds)
    sys.setswitchinterval(INTERRUPT_LATENCY_S)
    wire = CanWire()
    adapter = SlcanPty(wire.bus()).start()
    nodes = [
        CanopenNode(
            firmware,
            numbers[first : first + per_node],
            node_id_base + first // per_node,
            wire.bus(),
            od=object_dictionary(node_id_base + first // per_node, eds),
        ).start()
        for first in range(0, len(numbers), per_node)
    ]

    def close() -> None:
        for node in nodes:
            node.close()
        adapter.close()

    return adapter.path, close


def build(args: argparse.Namespace) -> tuple[Firmware, World, TrueStep]:
    """The firmware and the world the options describe, and the plant's true step at the
    reference settings; raises :class:`InputError` (or ValueError/FirmwareError) on bad input."""
    check_options(args)
    amplifier = AmplifierLimits(
        v_max_v=args.v_max,
        slew_rate_v_per_s=args.slew_v_per_s,
        current_limit_a=args.current_a,
        max_frequency_hz=args.max_frequency_hz,
    )
    config = FirmwareConfig(
        axes=args.axes,
        tick_hz=args.tick_hz,
        sample_rate_hz=args.sample_rate_hz,
        dac_buffer_s=args.dac_buffer_s,
        watchdog_s=args.watchdog_s,
        host_watchdog_s=args.host_watchdog_s,
        amplifier=amplifier,
        load_capacitance_f=args.load_capacitance_f,
    )
    firmware = Firmware(config)
    world = World(
        WorldConfig(
            part=args.part,
            support=args.support,
            tau_pa=args.tau_pa,
            tau_offset=args.tau_offset,
            kinetic_ratio=args.kinetic_ratio,
            scatter=args.scatter,
            seed=args.seed,
            plant_axis=args.plant_axis,
            plant=args.plant,
            poses=parse_poses(args.parts, "--parts"),
            lever_arm_m=args.lever_arm_m,
            camera=CameraConfig(args.camera_rate_hz, args.camera_noise_m, args.camera_latency_s),
            stack=StackParameters(
                gain_m_per_v=args.stack_gain_m_per_v,
                capacitance_f=args.load_capacitance_f,
                output_resistance_ohm=args.stack_output_resistance_ohm,
                resonance_hz=args.stack_resonance_hz,
                damping_ratio=args.stack_damping_ratio,
            ),
        ),
        config,
    )
    world.attach(firmware)
    reference = firmware.axis(args.plant_axis)
    reference.set_amplitude(amplifier.max_amplitude_vpp)
    step = world.true_step(reference)
    reference.set_amplitude(0.0)
    return firmware, world, step


def prepare(argv: list[str] | None) -> tuple[argparse.Namespace, Firmware, World, TrueStep]:
    """Parse, check and :func:`build`; bad input exits 2 with one line naming the option."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return (args, *build(args))
    except (InputError, ValueError, FirmwareError) as exc:
        parser.error(str(exc))


def main(argv: list[str] | None = None) -> int:
    for signum in SHUTDOWN_SIGNALS:  # while starting up, a signal ends the program at once
        signal.signal(signum, signal.SIG_DFL)
    args, firmware, world, step = prepare(argv)
    amplifier = firmware.config.amplifier

    wakeup = _catch_shutdown_signals()
    closers: list[Callable[[], None]] = []
    try:
        endpoints = start_endpoints(args, firmware, world, closers)
    except (InputError, ValueError, OSError) as exc:
        for close in reversed(closers):
            close()
        print(f"firmware_sim: error: {exc}", file=sys.stderr)
        return 2
    true = {
        **world.describe(),
        "step_up_m": step.up_m,
        "step_down_m": step.down_m,
        "step_scatter": step.scatter,
        "step_reference": {
            "frequency_hz": REFERENCE_FREQUENCY_HZ,
            "amplitude_v": amplifier.max_amplitude_vpp,
            "flyback_shape": "current-limited",
        },
    }
    print(
        json.dumps(
            {"ready": True, "pid": os.getpid(), "clock": args.clock, "endpoints": endpoints, "true": true}
        ),
        flush=True,
    )
    stop = threading.Event()
    clock: Clock = RealTimeClock() if args.clock == "real" else VirtualClock()
    ticker = threading.Thread(target=run_ticks, args=(firmware, clock, stop), name="tick", daemon=True)
    ticker.start()
    while ticker.is_alive() and not select.select([wakeup], [], [], 0.2)[0]:
        pass
    crashed = not ticker.is_alive()  # ended untold: threading's excepthook printed why
    # the backstop needs no thread and no GIL: SIGALRM's default action ends the process
    signal.signal(signal.SIGALRM, signal.SIG_DFL)
    signal.setitimer(signal.ITIMER_REAL, EXIT_DEADLINE_S)
    stop.set()
    ticker.join(STOP_JOIN_S)
    crashed = crashed or ticker.is_alive()
    firmware.shutdown()
    for close in reversed(closers):
        close()
    print(json.dumps({"stopped": True, "tick": firmware.tick_summary()}), file=sys.stderr)
    signal.setitimer(signal.ITIMER_REAL, 0)
    return 1 if crashed else 0


def run_ticks(firmware: Firmware, clock: Clock, stop: threading.Event) -> None:
    """The tick thread: tick until ``stop`` is set."""
    if clock.realtime:
        firmware.run(clock, stop)
        return
    while not stop.is_set():  # back to back, but let the front ends' threads in now and then
        firmware.run(clock, stop, max_ticks=VIRTUAL_TICKS_PER_YIELD)
        time.sleep(0)


def _catch_shutdown_signals() -> int:
    """SIGINT/SIGTERM from now on write to a pipe the main thread waits on; returns its
    read end.  The handler itself does nothing (the C-level handler writes the signal
    number to the wakeup fd), so it can take no lock another frame of the main thread holds."""
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)
    signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)
    for signum in SHUTDOWN_SIGNALS:
        signal.signal(signum, _ignore_here)
    return read_end


def _ignore_here(_signum: int, _frame: FrameType | None) -> None:
    """Python-level SIGINT/SIGTERM handler: nothing to do, the wakeup fd carries the signal."""


if __name__ == "__main__":
    status = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)  # all cleaned up; the interpreter's teardown can take a second when busy
