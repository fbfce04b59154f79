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
during start-up ends the program at once.  Every option is range-checked: bad
input is one line on stderr naming the option, exit code 2.
Protocol reference: docs/anc300-protocol.md.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable
from types import FrameType
from typing import NoReturn

from feeder.errors import InputError
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.planar_plant import DEFAULT_LEVER_ARM_M
from feeder.pose import parse_poses
from feeder.protocol.anc300 import DEFAULT_PASSWORD, DIALECTS
from feeder.protocol.eds import EDS_3AXIS_FILE, EDS_FILE, axis_count, object_dictionary
from firmware_sim.canopen_node import check_can_layout, serve_slcan_pty
from firmware_sim.clock import Clock, RealTimeClock, VirtualClock
from firmware_sim.console import ConsoleSession, LoginThrottle
from firmware_sim.firmware import (
    DEFAULT_DAC_BUFFER_S,
    DEFAULT_LOAD_CAPACITANCE_F,
    Axis,
    Firmware,
    FirmwareConfig,
    FirmwareError,
)
from firmware_sim.transports import (
    LineBroadcastServer,
    PtyConsole,
    SessionFactory,
    TcpConsoleServer,
    check_local,
)
from firmware_sim.world import PLANTS, CameraConfig, TrueStep, World, WorldConfig

REFERENCE_FREQUENCY_HZ = 100.0
VIRTUAL_TICKS_PER_YIELD = 10
SLOTS = FirmwareConfig().slots
MAX_TICK_HZ = 10_000.0
MAX_SAMPLE_RATE_HZ = 1e6
MAX_DAC_BUFFER_SAMPLES = 200_000
"""Per axis: --dac-buffer-s × --sample-rate-hz, and one tick's samples (memory, tick time)."""
MAX_DELAY_S = 10.0
MAX_WATCHDOG_S = 3600.0
MAX_CAMERA_RATE_HZ = 10_000.0
MAX_CAMERA_SIDE_PX = 8192
MIN_TAU_PA = 1e6
MAX_TAU_PA = 1e12
MAX_SEED = 2**63 - 1
MAX_PASSWORD_CHARS = 64
CANOPEN_MAX_NODE_ID = 127
SHUTDOWN_SIGNALS = (signal.SIGINT, signal.SIGTERM)
STOP_JOIN_S = 0.3
"""How long the main thread waits for the tick thread to finish its tick."""
EXIT_DEADLINE_S = 0.7
"""After SIGINT/SIGTERM the process is gone within this long: if the orderly shutdown
overruns it (a stuck tick), SIGALRM ends the process (exit status 128 + 14)."""


class OptionParser(argparse.ArgumentParser):
    """argparse with a one-line error (naming the option) and exit code 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"firmware_sim: error: {message}\n")


def in_range(lo: float, hi: float, *, lo_open: bool = False, integer: bool = False) -> Callable[[str], float]:
    """argparse type: a finite number (or an integer) in ``[lo, hi]`` (``(lo, hi]``)."""
    interval = _interval(lo, hi, lo_open, integer)

    def convert(text: str) -> float:
        try:
            value: float = int(text) if integer else float(text)
        except ValueError:
            kind = "an integer" if integer else "a number"
            raise argparse.ArgumentTypeError(f"expected {kind} in {interval}, got {text!r}") from None
        if not (
            (integer or math.isfinite(value))  # an int past a float's range stays an int
            and (lo < value if lo_open else lo <= value)
            and value <= hi
        ):
            raise argparse.ArgumentTypeError(f"must be in {interval}, got {text!r}")
        return value

    convert.__name__ = "integer" if integer else "number"
    return convert


def _interval(lo: float, hi: float, lo_open: bool, integer: bool) -> str:
    show = (lambda v: str(int(v))) if integer else (lambda v: f"{v:g}")
    return f"{'(' if lo_open else '['}{show(lo)}, {show(hi)}]"


def add_number(
    group: argparse._ArgumentGroup,
    flag: str,
    lo: float,
    hi: float,
    *,
    default: float | None,
    help: str = "",
    lo_open: bool = False,
    integer: bool = False,
    metavar: str | None = None,
) -> None:
    """An option taking a number in a stated range; the range goes into ``--help``."""
    interval = _interval(lo, hi, lo_open, integer)
    shown = "" if default is None else f", default {default:g}"
    group.add_argument(
        flag,
        type=in_range(lo, hi, lo_open=lo_open, integer=integer),
        default=default,
        metavar=metavar or ("N" if integer else "X"),
        help=f"{help} (in {interval}{shown})".strip(),
    )


def build_parser() -> argparse.ArgumentParser:
    amp = AmplifierLimits()
    parser = OptionParser(
        prog="python -m firmware_sim",
        description="Piezo amplifier firmware simulator (ANC300-compatible console) with "
        "the stick-slip plant and a camera behind it.  Prints one JSON ready "
        "line with the endpoints, runs until SIGINT/SIGTERM.",
    )
    ends = parser.add_argument_group("endpoints (servers bind to 127.0.0.1 only)")
    ends.add_argument(
        "--console",
        action="append",
        metavar="SPEC",
        help="pty, or tcp:127.0.0.1:PORT (PORT 0 = any free port; the ANC300's "
        "is 7230); repeatable; default: pty",
    )
    ends.add_argument(
        "--serial-login", action="store_true", help="ask for the password on the pty too (TCP always asks)"
    )
    ends.add_argument(
        "--dialect",
        choices=DIALECTS,
        default="extended",
        help="console verbs: anc300 = only a real ANC300's (every extension "
        "verb gets its error reply; what the daemon starts), extended = "
        "plus the test and diagnostic extensions (default)",
    )
    ends.add_argument(
        "--password",
        default=DEFAULT_PASSWORD,
        help="console password (default %(default)s, as on real units)",
    )
    ends.add_argument("--sensor", metavar="SPEC", help="camera frame stream, tcp:127.0.0.1:PORT (JSON lines)")
    add_number(
        ends,
        "--camera-http",
        0,
        65535,
        integer=True,
        default=None,
        metavar="PORT",
        help="microscope camera on http://127.0.0.1:PORT (0 = any free port): "
        "/video.mjpg, /frame.png, /truth.json (endpoint camera_http)",
    )
    add_number(ends, "--camera-http-fps", 0, 100, lo_open=True, default=10.0, help="its frame rate, Hz")
    add_number(ends, "--camera-pixel-size-m", 1e-9, 1e-3, default=1e-6, help="its pixel size, m")
    add_number(
        ends, "--camera-width-px", 16, MAX_CAMERA_SIDE_PX, integer=True, default=1024, help="its width, px"
    )
    add_number(
        ends, "--camera-height-px", 16, MAX_CAMERA_SIDE_PX, integer=True, default=1024, help="its height, px"
    )
    add_extra_front_end_arguments(ends)

    fw = parser.add_argument_group("firmware")
    fw.add_argument(
        "--clock",
        choices=("real", "virtual"),
        default="real",
        help="real: 1 tick per period of wall time; virtual: ticks back to back "
        "(deterministic, uses a CPU core)",
    )
    add_number(
        fw, "--axes", 1, SLOTS, integer=True, default=3, help=f"configured axes 1..N (of {SLOTS} slots)"
    )
    add_number(
        fw,
        "--tick-hz",
        1,
        MAX_TICK_HZ,
        default=1000.0,
        help="tick rate, Hz; --sample-rate-hz must be a whole multiple of it",
    )
    add_number(fw, "--sample-rate-hz", 1000, MAX_SAMPLE_RATE_HZ, default=100_000.0, help="DAC rate, Hz")
    add_number(
        fw,
        "--dac-buffer-s",
        0,
        MAX_DELAY_S,
        lo_open=True,
        default=DEFAULT_DAC_BUFFER_S,
        help="how far the tick keeps the DAC buffer ahead, s: a tick this late still "
        f"does not starve the DAC (at most {MAX_DAC_BUFFER_SAMPLES:g} samples)",
    )
    add_number(
        fw,
        "--watchdog-s",
        0,
        MAX_WATCHDOG_S,
        lo_open=True,
        default=0.25,
        help="a tick this late grounds every axis, s",
    )
    add_number(
        fw,
        "--host-watchdog-s",
        0,
        MAX_WATCHDOG_S,
        default=0.0,
        help="ground a moving axis after this long without a host command, s (0 = off)",
    )
    add_number(fw, "--v-max", 0, 1000, lo_open=True, default=amp.v_max_v, help="output rail, V")
    add_number(
        fw,
        "--slew-v-per-s",
        0,
        1e9,
        lo_open=True,
        default=amp.slew_rate_v_per_s,
        help="output slew rate, V/s",
    )
    add_number(
        fw, "--current-a", 0, 100, lo_open=True, default=amp.current_limit_a, help="output current limit, A"
    )
    add_number(
        fw,
        "--max-frequency-hz",
        REFERENCE_FREQUENCY_HZ,
        100_000,
        default=amp.max_frequency_hz,
        help="highest stepping frequency, Hz (below half --sample-rate-hz)",
    )
    add_number(
        fw,
        "--load-capacitance-f",
        1e-12,
        1e-3,
        default=DEFAULT_LOAD_CAPACITANCE_F,
        help="stack capacitance the current limit is enforced for, F",
    )

    world = parser.add_argument_group("world (the plant's true parameters)")
    world.add_argument("--part", default="300x300x50", help="LxWxT in µm")
    world.add_argument("--support", default="flat", help="flat or grooved")
    tau = world.add_mutually_exclusive_group()
    tau.add_argument(
        "--tau-pa",
        type=in_range(MIN_TAU_PA, MAX_TAU_PA),
        help="true shear strength τ, Pa (default: drawn in 22.18 ± 3.15 GPa from "
        f"--seed; in [{MIN_TAU_PA:g}, {MAX_TAU_PA:g}])",
    )
    tau.add_argument(
        "--tau-offset",
        type=in_range(-0.99, 10),
        help="true τ relative to the nominal 22.18 GPa, e.g. 0.15 = +15 %% (in [-0.99, 10])",
    )
    add_number(world, "--kinetic-ratio", 0, 1, lo_open=True, default=0.8, help="F_k/F_s")
    add_number(
        world, "--scatter", 0, 1, default=0.02, help="step-to-step relative scatter of the static friction"
    )
    add_number(world, "--seed", 0, MAX_SEED, integer=True, default=0, help="seed of the world's random draws")
    add_number(
        world,
        "--plant-axis",
        1,
        SLOTS,
        integer=True,
        default=1,
        help="axis wired to the stack (at most --axes)",
    )
    world.add_argument(
        "--plant",
        choices=PLANTS,
        default="line",
        help="line: one stack on --plant-axis (default); planar: axes 1-3 drive the "
        "plate's x, y and θ, parts at --parts",
    )
    world.add_argument(
        "--parts",
        metavar="X,Y,PSI;...",
        default="0,0,0",
        help="planar: the parts' poses in the plate frame (m, m, rad; origin at "
        "the rotation centre O), ';' between parts (default %(default)s)",
    )
    add_number(
        world,
        "--lever-arm-m",
        1e-6,
        1.0,
        default=DEFAULT_LEVER_ARM_M,
        help="planar: radius about O at which the θ stack turns the plate, m",
    )
    add_number(
        world, "--camera-rate-hz", 0.1, MAX_CAMERA_RATE_HZ, default=100.0, help="camera frame rate, Hz"
    )
    add_number(world, "--camera-noise-m", 0, 1e-3, default=50e-9, help="position noise (1σ), m")
    add_number(world, "--camera-latency-s", 0, MAX_DELAY_S, default=0.010, help="exposure to frame out, s")
    return parser


def add_extra_front_end_arguments(group: argparse._ArgumentGroup) -> None:
    """Options of further front ends (e.g. CANopen) go here."""
    group.add_argument(
        "--can",
        choices=("slcan-pty",),
        help="CANopen: the axes as nodes (per --can-eds) behind an emulated SLCAN "
        "adapter on a pty (endpoint slcan_pty; docs/canopen.md)",
    )
    group.add_argument(
        "--can-eds",
        default=EDS_FILE,
        metavar="EDS",
        help=f"the nodes' EDS, which says how many axes a node has: {EDS_FILE} (one axis per "
        f"node, default), {EDS_3AXIS_FILE} (three), or the path of one",
    )
    add_number(
        group,
        "--can-node-id-base",
        1,
        CANOPEN_MAX_NODE_ID,
        integer=True,
        default=1,
        help="CANopen node id of axis 1 (with A axes per node, axis n is on node base + (n - 1) div A)",
    )


def _tcp_spec(spec: str, option: str) -> tuple[str, int]:
    """``tcp:HOST:PORT`` or ``socket://HOST:PORT`` → (host, port)."""
    rest = spec.removeprefix("socket://") if spec.startswith("socket://") else ""
    if not rest:
        kind, _, rest = spec.partition(":")
        rest = rest if kind == "tcp" else ""
    host, _, port = rest.rpartition(":")
    if not host or not (port.isascii() and port.isdigit() and int(port) <= 65535):
        raise InputError(
            option, f"expected tcp:127.0.0.1:PORT or socket://127.0.0.1:PORT (PORT 0..65535), got {spec!r}"
        )
    try:
        check_local(host)
    except ValueError as exc:
        raise InputError(option, str(exc)) from None
    return host, int(port)


def check_options(args: argparse.Namespace) -> None:
    """What the option types cannot check alone; raises :class:`InputError` naming the option."""
    ratio = args.sample_rate_hz / args.tick_hz
    if ratio < 1 or abs(ratio - round(ratio)) > 1e-9:
        raise InputError(
            "--sample-rate-hz",
            f"must be a whole multiple of --tick-hz ({args.tick_hz:g}), got {args.sample_rate_hz:g}",
        )
    if max(args.dac_buffer_s * args.sample_rate_hz, ratio) > MAX_DAC_BUFFER_SAMPLES:
        option = "--dac-buffer-s" if ratio <= MAX_DAC_BUFFER_SAMPLES else "--tick-hz"
        raise InputError(
            option,
            f"the DAC buffer (--dac-buffer-s × --sample-rate-hz, at least "
            f"one tick) would exceed {MAX_DAC_BUFFER_SAMPLES:g} samples",
        )
    if args.max_frequency_hz >= args.sample_rate_hz / 2:
        raise InputError(
            "--max-frequency-hz",
            f"must be below half the DAC rate "
            f"({args.sample_rate_hz / 2:g} Hz), got {args.max_frequency_hz:g}",
        )
    if args.camera_rate_hz > args.sample_rate_hz:
        raise InputError(
            "--camera-rate-hz",
            f"must not exceed --sample-rate-hz ({args.sample_rate_hz:g}), got {args.camera_rate_hz:g}",
        )
    if args.plant_axis > args.axes:
        raise InputError(
            "--plant-axis", f"must be one of the {args.axes} configured axes, got {args.plant_axis}"
        )
    if args.can:
        per_node = axis_count(object_dictionary(args.can_node_id_base, args.can_eds, "--can-eds"))
        check_can_layout(args.axes, per_node, args.can_node_id_base, args.can_eds)
    password = args.password
    if not (
        0 < len(password) <= MAX_PASSWORD_CHARS
        and password.isascii()
        and password.isprintable()
        and password == password.strip()
    ):
        raise InputError(
            "--password",
            f"must be 1..{MAX_PASSWORD_CHARS} printable ASCII characters without leading or trailing blanks",
        )
    for spec in args.console or []:
        if spec != "pty":
            _tcp_spec(spec, "--console")
    if args.sensor:
        _tcp_spec(args.sensor, "--sensor")


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
        from firmware_sim.camera_render import CameraModel

        http = serve_world_camera(
            world,
            args.camera_http,
            args.camera_http_fps,
            args.camera_pixel_size_m,
            args.camera_latency_s,
            CameraModel(width_px=args.camera_width_px, height_px=args.camera_height_px),
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
