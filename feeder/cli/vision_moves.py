"""``feeder vision calibrate-moves``: the camera calibration from plate moves the amplifier makes.

Opens the daemon configuration's amplifier and camera (or, with no hardware named, starts the
simulator as the daemon would), moves the plate by DC offsets on x, y and θ
(:mod:`feeder.vision.offset_moves`) and reports, writes or stores the calibration as ``feeder
vision calibrate`` does.  The daemon holds the same amplifier: stop it first (its state
directory's lock says whether one runs there).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import signal
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from feeder.cli.arguments import add_sim_arg, float_in, int_in, output_path, positive_float
from feeder.cli.calibration_report import check_target, emit_calibration
from feeder.daemon.client import DEFAULT_TIMEOUT_S, Client
from feeder.daemon.client_connection import default_socket_path
from feeder.errors import FeederError, InputError
from feeder.files import save_figure
from feeder.vision.calibration import CameraCalibration
from feeder.vision.offset_moves import (
    FIRMWARE_SIM_GAIN_M_PER_V,
    SLIP_FRACTION,
    SLIP_FRACTION_RANGE,
    OffsetMoves,
    measure,
)


def register(vision: Any) -> None:
    moves = vision.add_parser(
        "calibrate-moves",
        help="calibration from plate moves the amplifier makes (DC offsets; stop the daemon first)",
    )
    moves.add_argument("--config", type=Path, help="the daemon's TOML (default: the simulated plane)")
    moves.add_argument(
        "--daemon",
        action="store_true",
        help="ask the running daemon to make the moves with its amplifier and camera (no restart; "
        "--save-state stores it for its next move)",
    )
    moves.add_argument(
        "--socket", type=Path, help=f"with --daemon: its socket (default {default_socket_path()})"
    )
    moves.add_argument(
        "--timeout",
        type=positive_float,
        default=DEFAULT_TIMEOUT_S,
        metavar="SECONDS",
        help=f"with --daemon: give up (exit 3) when it answers no heartbeat within SECONDS (its "
        f"moves then stop, as when this command is killed); the moves may take longer (default "
        f"{DEFAULT_TIMEOUT_S:g})",
    )
    moves.add_argument(
        "--volts",
        type=float_in(1.0, 200.0),
        default=100.0,
        help="offset each axis is held at, 1–200 V (default 100; an ANC300 takes up to 150)",
    )
    moves.add_argument(
        "--stack-gain",
        type=float_in(1e-12, 1e-3),
        metavar="M_PER_V",
        help="the plate's static move per volt of offset, m/V (the stacks' stroke per volt, "
        f"e.g. 7e-8); default the configuration's [stack] gain_m_per_v, else firmware_sim's "
        f"{FIRMWARE_SIM_GAIN_M_PER_V:g} on the simulator; required on hardware without [stack]",
    )
    moves.add_argument(
        "--increment",
        type=float_in(1e-4, 1.0),
        default=0.05,
        metavar="V",
        help="the offset ramps in steps of at most this, 1e-4–1 V (default 0.05; a jump is a flyback: "
        "the parts slip)",
    )
    moves.add_argument(
        "--frames",
        type=int_in(1, 1000),
        default=10,
        help="frames averaged per position, 1–1000 (default 10)",
    )
    moves.add_argument(
        "--slip-fraction",
        type=float_in(*SLIP_FRACTION_RANGE),
        default=SLIP_FRACTION,
        metavar="F",
        help="parts that come back further than this fraction of the smallest move slipped: nothing "
        f"is stored, {SLIP_FRACTION_RANGE[0]:g}–{SLIP_FRACTION_RANGE[1]:g} (default {SLIP_FRACTION:g}; "
        "stacks that creep back short of their start by more need more)",
    )
    add_sim_arg(moves, "--sim-arg=--camera-mirrored")
    moves.add_argument(
        "--out", type=output_path, help="write the calibration JSON (for `vision locate --calibration`)"
    )
    moves.add_argument(
        "--save-state", action="store_true", help="store it for the daemon (used from its next start)"
    )
    moves.add_argument(
        "--plot",
        type=output_path,
        help="PNG of the parts' moves in the image (magnified) and the plate's axes the fit found",
    )
    moves.add_argument("--state-dir", type=Path, help="the daemon's state directory (default: the config's)")
    moves.add_argument("--json", action="store_true", help="print one JSON object")
    moves.set_defaults(handler=run_calibrate_moves)


def run_calibrate_moves(args: argparse.Namespace) -> int:
    if args.daemon:
        return _by_the_daemon(args)
    if args.socket is not None:
        raise InputError("--socket", "only with --daemon")
    from feeder.daemon.config import embedded_plane
    from feeder.daemon.config_file import load_config
    from feeder.daemon.links import open_links
    from feeder.daemon.service import lock_state

    check_target(args.out, "--out")
    check_target(args.plot, "--plot")
    config = load_config(args.config)
    if args.config is None:
        config = embedded_plane(config)
    config = config.with_state_dir(args.state_dir).with_simulator_args(args.sim_arg)
    if not {"x", "y"} <= set(config.plate.axes):
        raise InputError("plate.axes", "the plate moves need the x and y axes")
    gain = args.stack_gain or config.stack_gain_m_per_v
    if gain is None:
        raise InputError(
            "--stack-gain",
            "required on hardware without [stack] gain_m_per_v: the plate's move per volt of offset (m/V)",
        )
    limits = config.amplifier.limits
    if not limits.v_min_v <= args.volts <= limits.v_max_v:
        raise InputError(
            "--volts",
            f"{args.volts:g} V is beyond the amplifier's output, {limits.v_min_v:g}–{limits.v_max_v:g} V "
            f"(amplifier.model {config.amplifier.model})",
        )
    moves = OffsetMoves(
        volts=args.volts,
        stack_gain_m_per_v=gain,
        lever_arm_m=config.plate.lever_arm_m,
        increment_v=args.increment,
        frames=args.frames,
        slip_fraction=args.slip_fraction,
    )
    lock = lock_state(config.database_path)  # no daemon drives this amplifier meanwhile
    try:
        links = open_links(config)
        try:
            with _interrupted_by_signals():
                report = _measure(links, moves)
        finally:
            links.close()
        report["configured_pixel_size_m"] = config.camera.pixel_size_m
        located = links.configured_calibration()
        if located is not None and config.plate.planar:  # the daemon checks this at its start
            outside = config.camera.travel_outside(located.updated(report), config.part, config.loop)
            if outside is not None:  # stored all the same: narrowing the travel keeps it
                report["warnings"].append(f"with this calibration the daemon refuses to start: {outside}")
        if args.plot is not None and located is not None:  # drawn also when the parts slipped
            size = (config.camera.width_px, config.camera.height_px)
            plot_moves(report, located.updated(report), size, args.plot)
            report["plot"] = str(args.plot)
        _warn_and_check(report)
        if args.save_state:  # emit_calibration stores it where the daemon of this config looks
            args.state_dir = config.state_dir
        return emit_calibration(report, args)
    finally:
        lock.close()


def _warn_and_check(report: dict[str, Any]) -> None:
    """Print the report's warnings; a calibration whose parts slipped goes no further."""
    for warning in report["warnings"]:
        print(f"feeder vision calibrate-moves: warning: {warning}", file=sys.stderr)
    if report["slipped"]:
        raise FeederError("the parts slipped during the moves: nothing stored or written")


def _by_the_daemon(args: argparse.Namespace) -> int:
    """``--daemon``: the running daemon makes the moves (the socket's ``calibrate_camera``) and,
    with ``--save-state``, stores the calibration itself.  Ctrl-C, SIGTERM and SIGHUP stop its
    moves (every axis grounded, nothing stored), as they end this command's own; so does this
    command's end in any other way (killed, or giving up on a silent daemon after ``--timeout``):
    the daemon stops the moves of a client that hangs up."""
    own = (("--config", args.config), ("--state-dir", args.state_dir), ("--sim-arg", args.sim_arg))
    for flag, given in own:
        if given:
            raise InputError(flag, "not with --daemon: the daemon's own configuration and state are used")
    check_target(args.out, "--out")
    check_target(args.plot, "--plot")
    with _interrupted_by_signals(), Client(args.socket, timeout_s=args.timeout) as client:
        print("the daemon moves the plate (Ctrl-C stops it):", file=sys.stderr)
        try:
            report = client.calibrate_camera(
                volts=args.volts,
                stack_gain_m_per_v=args.stack_gain,
                increment_v=args.increment,
                frames=args.frames,
                slip_fraction=args.slip_fraction,
                save=args.save_state,
                progress=lambda step: print(step, file=sys.stderr),
            )
        except KeyboardInterrupt:
            # stop on a second connection while this one is open: its close stops the moves too,
            # and a stop arriving after that would find none (and say they had ended)
            with Client(args.socket, timeout_s=args.timeout) as stopper:
                stopped = stopper.stop().stopped
            print(
                "the daemon's plate moves were stopped: every axis grounded, nothing stored"
                if stopped
                else "the daemon's plate moves had ended (feeder status shows the calibration in use)",
                file=sys.stderr,
            )
            raise
    if args.plot is not None:
        width, height = report["image_px"]
        plot_moves(report, fitted(report, (width, height)), (width, height), args.plot)
        report["plot"] = str(args.plot)
    _warn_and_check(report)
    if report["travel_outside"] is not None:  # the running daemon would refuse every move with it
        raise FeederError(
            f"with this calibration the daemon would refuse every move: {report['travel_outside']}; "
            "nothing stored or written: narrow [control]'s travel, restart the daemon, calibrate again"
        )
    if report["saved"]:
        report["note"] = "stored by the daemon: used from its next move on"
    args.save_state = False  # the daemon stored it in its own state
    return emit_calibration(report, args)


def fitted(report: dict[str, Any], image_px: tuple[int, int]) -> CameraCalibration:
    """The calibration the report gives (O at the image centre when θ did not move)."""
    width, height = image_px
    centred = CameraCalibration(report["pixel_size_m"], 0.0, False, (width - 1) / 2, (height - 1) / 2)
    return centred.updated(report)


@contextlib.contextmanager
def _interrupted_by_signals() -> Iterator[None]:
    """SIGTERM and SIGHUP end the moves as Ctrl-C does: the axes grounded on the way out (a real
    ANC300 has no host watchdog: an axis left in its offset mode stays there)."""

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)

    previous = {sig: signal.signal(sig, interrupt) for sig in (signal.SIGTERM, signal.SIGHUP)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _measure(links: Any, moves: OffsetMoves) -> dict[str, Any]:
    """Open the amplifier's axes and the camera, move, release them (measure() grounds the axes)."""
    from feeder.drivers.axes import Axes

    amplifiers = links.open_amplifier()
    assert isinstance(amplifiers, Axes)  # a plate with x and y (run_calibrate_moves checked)
    try:  # measure() grounds the axes it moved, and names any it could not
        calibration = links.configured_calibration()
        if calibration is None:
            raise InputError("camera", "the plate moves are measured by a camera ([camera] address)")
        with links.open_sensor(calibration) as sensor:
            return measure(
                amplifiers, sensor, calibration, moves, progress=lambda line: print(line, file=sys.stderr)
            )
    finally:
        amplifiers.release()


def plot_moves(
    report: dict[str, Any], calibration: CameraCalibration, size_px: tuple[int, int], path: Path
) -> None:
    """The image (``size_px``: width, height): each part's move per axis from where it rested
    (the mean of before and after) to where the offset held it, and back (the miss: a slip),
    magnified alike; the plate's +x and +y at O as ``calibration`` (the fit) maps them; O."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    width, height = size_px
    moves = {axis: np.array(rows, dtype=float).reshape(-1, 3, 2) for axis, rows in report["moves_px"].items()}
    longest = max(float(np.max(np.hypot(*(m[:, 1] - m[:, [0, 2]].mean(axis=1)).T))) for m in moves.values())
    gain = 10 ** math.floor(math.log10(0.08 * math.hypot(width, height) / max(longest, 1e-9)))
    fig, ax = plt.subplots(figsize=(7, 7 * height / width))
    ax.add_patch(plt.Rectangle((-0.5, -0.5), width, height, fill=False, color="0.6"))
    colours = {"x": "tab:red", "y": "tab:green", "theta": "tab:blue"}
    for axis, m in moves.items():
        rest = m[:, [0, 2]].mean(axis=1)
        for k, (start, at, back) in enumerate(zip(rest, m[:, 1], m[:, 2] - m[:, 0], strict=True)):
            ax.annotate(
                "",
                start + gain * (at - start),
                start,
                arrowprops={"arrowstyle": "->", "color": colours[axis], "lw": 1.5},
            )
            ax.plot(*zip(start, start + gain * back, strict=True), color="k", lw=2)
            if axis == "x":
                ax.text(start[0], start[1], f" {k + 1}", fontsize=8)
        ax.plot([], [], color=colours[axis], label=f"{axis} move, × {gain:g}")
    ax.plot([], [], color="k", lw=2, label=f"after − before (a slip), × {gain:g}")
    o = calibration.to_image(0.0, 0.0)
    reach = 0.2 * min(width, height) * calibration.pixel_size_m
    for name, end in (("plate +x", (reach, 0.0)), ("plate +y", (0.0, reach))):
        tip = calibration.to_image(*end)
        ax.annotate("", tip, o, arrowprops={"arrowstyle": "-|>", "color": "0.3"})
        ax.text(tip[0], tip[1], " " + name, color="0.3", fontsize=8)
    if report.get("origin_x_px") is not None:
        ax.plot(o[0], o[1], "+", color="k", ms=12)
        ax.add_patch(plt.Circle(o, report["origin_uncertainty_px"], fill=False, color="k", ls=":"))
        ax.text(o[0], o[1], f" O ± {report['origin_uncertainty_px']:.1f} px", fontsize=8, va="top")
    ax.set_xlim(-0.05 * width, 1.05 * width)
    ax.set_ylim(1.05 * height, -0.05 * height)  # image rows grow downwards
    ax.set_aspect("equal")
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    ax.legend(loc="lower right", fontsize=7)
    verdict = "SLIPPED, not stored" if report["slipped"] else f"back within {report['returned_px']:.3f} px"
    ax.set_title(
        f"{report['pixel_size_m'] * 1e6:.4f} µm/px, turned {math.degrees(report['rotation_rad']):.2f}°"
        f"{', mirrored' if report['mirrored'] else ''}; {verdict}",
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, path)
