"""Command-line options of ``python -m firmware_sim`` and the checks on them.

Every option is range-checked by its argparse type (:func:`in_range`, the range
stated in ``--help``); :func:`check_options` checks what needs several options
at once.  Bad input is one line on stderr naming the option, exit code 2
(:class:`OptionParser`).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import NoReturn

from feeder.errors import InputError
from feeder.plant.amplifier import AmplifierLimits
from feeder.plant.planar_plant import DEFAULT_LEVER_ARM_M
from feeder.plant.stack import STACK_FIELDS, STACK_RANGES, StackParameters
from feeder.pose import MAX_POSE_M, part_poses
from feeder.protocol.anc300 import DEFAULT_PASSWORD, DIALECTS
from feeder.protocol.eds import EDS_3AXIS_FILE, EDS_FILE, axis_count, object_dictionary
from firmware_sim.firmware import DEFAULT_DAC_BUFFER_S, DEFAULT_LOAD_CAPACITANCE_F, FirmwareConfig
from firmware_sim.transports import check_local
from firmware_sim.world import PLANTS

REFERENCE_FREQUENCY_HZ = 100.0
"""Stepping frequency of the true step the ready line reports, Hz; the lowest --max-frequency-hz."""
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
        ends,
        "--camera-rotation-rad",
        -math.pi,
        math.pi,
        default=0.0,
        help="how far the image is turned from the plate's axes, rad (a camera's mounting)",
    )
    ends.add_argument(
        "--camera-mirrored",
        action="store_true",
        help="the image is mirrored (a camera seeing the plate's y flipped)",
    )
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
        *STACK_RANGES["capacitance_f"],
        default=DEFAULT_LOAD_CAPACITANCE_F,
        help="stack capacitance, F: the current limit is enforced for it, and the world's stacks have it",
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
        type=part_poses_text,
        metavar="X,Y,PSI;...",
        default="0,0,0",
        help=f"planar: the parts' poses in the plate frame (m, m, rad; origin at the rotation "
        f"centre O; |X|, |Y| ≤ {MAX_POSE_M:g} m, |PSI| ≤ 2π), ';' between parts (default %(default)s)",
    )
    add_number(
        world,
        "--lever-arm-m",
        1e-6,
        1.0,
        default=DEFAULT_LEVER_ARM_M,
        help="planar: radius about O at which the θ stack turns the plate, m",
    )
    stack = StackParameters()
    for field in ("gain_m_per_v", "resonance_hz", "damping_ratio", "output_resistance_ohm"):  # C: above
        unit, what = STACK_FIELDS[field]
        add_number(
            world,
            "--stack-" + field.replace("_", "-"),
            *STACK_RANGES[field],
            default=getattr(stack, field),
            help=what + (f", {unit}" if unit else ""),
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


def tcp_spec(spec: str, option: str) -> tuple[str, int]:
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


def part_poses_text(text: str) -> str:
    """argparse type of ``--parts``: the text, once each part's pose is one on the plate
    (:func:`~feeder.pose.part_poses`, as the daemon's ``[plate] parts``)."""
    try:
        part_poses(text, "--parts")
    except InputError as err:
        raise argparse.ArgumentTypeError(err.message) from None
    return text


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
            tcp_spec(spec, "--console")
    if args.sensor:
        tcp_spec(args.sensor, "--sensor")


def check_can_layout(axes: int, per_node: int, node_id_base: int, eds: str) -> None:
    """``axes`` firmware axes fit whole nodes of ``per_node`` axes with ids in 1..127;
    :class:`InputError` naming the option otherwise."""
    if axes % per_node:
        raise InputError("--can-eds", f"{eds} has {per_node} axes per node; --axes {axes} is not a multiple")
    last = node_id_base + axes // per_node - 1
    if not 1 <= node_id_base <= last <= 127:
        raise InputError("--can-node-id-base", f"node ids {node_id_base}..{last} leave CANopen's 1..127")
