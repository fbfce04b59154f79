"""``feeder daemon``: run the control daemon in the foreground until SIGINT/SIGTERM."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import signal
import socket
import sys
import threading
import time
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from feeder.cli.arguments import add_sim_arg, float_in
from feeder.cli.output import print_json
from feeder.daemon.config import TRANSPORTS, DaemonConfig, HttpConfig, embedded_plane, uses_camera
from feeder.daemon.config_file import load_config
from feeder.daemon.launcher import LaunchError
from feeder.daemon.links import hardware_sensor, spawn_simulator
from feeder.daemon.socket_server import check_socket_path
from feeder.daemon.state_files import StoreError, check_state_file, move_aside
from feeder.drivers.amplifier import AmplifierError
from feeder.drivers.sensor import CameraError, SensorLost
from feeder.errors import InputError
from feeder.web.listener import listen

if TYPE_CHECKING:
    from feeder.daemon.runner import RunningDaemon
    from feeder.web.server import ConsoleServer


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "daemon", help="run the control daemon (no config: the simulated plane, x, y and θ)"
    )
    parser.add_argument("--config", type=Path, help="TOML configuration (see docs/daemon.md)")
    parser.add_argument(
        "--transport", choices=TRANSPORTS, help="amplifier link, overriding the configuration"
    )
    world = parser.add_mutually_exclusive_group()
    world.add_argument(
        "--plane",
        action="store_true",
        help="with --config: its simulated amplifier in the embedded planar world (axes x, y, θ, "
        "±2.4 mm travel, the simulator's camera; parts from its [plate] parts). Without "
        "--config this is the default",
    )
    world.add_argument(
        "--line",
        action="store_true",
        help="the embedded one-axis world instead of the plane: x only, ±5 mm, the simulator's "
        "position stream (no camera)",
    )
    parser.add_argument("--state-dir", type=Path, help="calibration/history database directory")
    parser.add_argument("--socket", type=Path, help="control socket path")
    add_sim_arg(parser, "--sim-arg=--seed=3")
    parser.add_argument(
        "--json", action="store_true", help="print the ready object (socket, endpoints, ...) as JSON"
    )
    parser.add_argument(
        "--http",
        metavar="HOST:PORT",
        help="serve the operator's console in the browser (e.g. 127.0.0.1:8470; loopback only "
        "unless the configuration's [http] allow_remote; see docs/console.md)",
    )
    parser.add_argument(
        "--reset-state",
        action="store_true",
        help="move the state database aside (renamed NAME.TIMESTAMP.bak) and "
        "start with a fresh one: calibration and history start empty",
    )
    parser.add_argument(
        "--wait-for-hardware",
        type=float_in(0.0, 86400.0),
        default=0.0,
        metavar="SECONDS",
        help="at start, keep trying to reach the amplifier and the camera (or sensor) this long, "
        "every 1-30 s (e.g. under systemd, before the devices are up); default 0: exit 1 at once",
    )
    parser.add_argument(
        "--log-level",
        choices=LOG_LEVELS,
        default="info",
        help="log to stderr and to daemon.log in the state directory (default %(default)s)",
    )
    parser.set_defaults(handler=run)


LOG_LEVELS = ("debug", "info", "warning", "error")
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
QUIET_LIBRARIES = ("canopen", "can")
"""Libraries whose INFO is chatter (canopen logs every SDO and PDO set-up: ~80 lines at a CAN
start): they log warnings and worse unless ``--log-level debug``."""


def setup_logging(level: str, log_file: Path) -> None:
    """The daemon logs to stderr and to ``log_file`` (appended, owner-only); :class:`InputError`
    naming the state directory when the log cannot be written there (a file, read-only)."""
    try:
        log_file.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        handlers: list[logging.Handler] = [
            logging.StreamHandler(sys.stderr),
            logging.FileHandler(log_file, encoding="utf-8"),
        ]
        log_file.chmod(0o600)
    except OSError as err:
        raise InputError(
            str(log_file.parent), f"the state directory cannot hold the log: {err.strerror or err}"
        ) from None
    logging.basicConfig(level=level.upper(), format=LOG_FORMAT, handlers=handlers, force=True)
    for name in QUIET_LIBRARIES:
        logging.getLogger(name).setLevel(logging.DEBUG if level == "debug" else logging.WARNING)


def run(args: argparse.Namespace) -> int:
    if args.line and args.config is not None:
        print(
            "feeder daemon: error: --line: only without --config (its [plate] names the axes)",
            file=sys.stderr,
        )
        return 2
    config = load_config(args.config)
    if args.transport:
        config = config.with_transport(args.transport)
    if args.plane or (args.config is None and not args.line):
        config = embedded_plane(config)
    config = config.with_state_dir(args.state_dir)
    if args.socket:
        config = dataclasses.replace(config, socket_path=args.socket)
    config = config.with_simulator_args(args.sim_arg)
    if args.http:
        config = dataclasses.replace(
            config, http=(config.http or HttpConfig()).listening_on(args.http, "--http")
        )
    hardware_sensor(config, str(args.config or "config"))  # refused before anything is written
    check_socket_path(config.socket_path)  # a file or a too long path left daemon.log behind
    # a taken port too: it was found after the simulator had started and planned (~27 s), a
    # fresh state database and token left behind
    listener = None if config.http is None else listen(config.http.host, config.http.port)
    setup_logging(args.log_level, config.state_dir / "daemon.log")
    if args.reset_state:
        from feeder.daemon.service import lock_state  # the daemon's own modules load with it below

        with lock_state(config.database_path):  # not a running daemon's database (exit 2)
            moved = move_aside(config.database_path)
        if moved is not None:
            logging.getLogger(__name__).warning("state database moved aside to %s", moved)
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        running = launch_when_reachable(config, args.wait_for_hardware, stop)
    except StoreError as err:  # the state file is not ours: bad input, left untouched
        print(f"feeder daemon: error: {err}", file=sys.stderr)
        return 2
    except (AmplifierError, SensorLost, CameraError, LaunchError) as err:
        print(f"feeder daemon: error: {err}", file=sys.stderr)
        return 1
    if running is None:  # stopped while waiting for the hardware
        return 0
    try:
        console = start_console(config, running, listener)
    except InputError:
        running.stop()
        raise
    ready = {
        "ready": True,
        "socket": str(config.socket_path),
        "database": str(config.database_path),
        **running.links.describe(),
        **({} if console is None else {"console_url": console.token_url}),
    }
    if args.json:
        print_json(ready)
    else:
        print(
            f"feeder daemon: listening on {config.socket_path} "
            f"({ready['transport']}{', simulated' if ready['simulated'] else ''})"
        )
        if console is not None:
            print(f"feeder daemon: console at {console.token_url}")
    sys.stdout.flush()
    while not stop.is_set() and not running.daemon.wait(0.2):
        pass
    # the moves stop and the output is grounded first: the console waits (up to 5 s) for its
    # requests in flight, a waiting move among them, which only the daemon's shutdown ends
    running.daemon.shutdown()
    if console is not None:
        console.stop()
    running.stop()
    if not args.json:
        print("feeder daemon: stopped", file=sys.stderr)
    return 0


def launch(config: DaemonConfig) -> RunningDaemon:
    """:func:`~feeder.daemon.runner.start_daemon` with the embedded simulator started first:
    it loads while this process imports the planner and plans (~2.5 s sooner ready).  A state
    file that is no database is refused before anything starts."""
    if config.database_path.exists():
        check_state_file(config.database_path)
    simulator = spawn_simulator(config)
    from feeder.daemon.runner import start_daemon  # heavy: imported while the simulator loads

    return start_daemon(config, simulator)


WAIT_FIRST_S = 1.0
WAIT_MAX_S = 30.0


def launch_when_reachable(config: DaemonConfig, wait_s: float, stop: threading.Event) -> RunningDaemon | None:
    """:func:`launch`, tried again while the amplifier or the camera cannot be reached, for up to
    ``wait_s`` (every 1 s, doubling up to 30 s; each failure logged); None if ``stop`` is set
    meanwhile.  The last failure is raised."""
    deadline = time.monotonic() + wait_s
    delay = WAIT_FIRST_S
    log = logging.getLogger(__name__)
    while True:
        try:
            return launch(config)
        except (AmplifierError, SensorLost, CameraError) as err:
            left = deadline - time.monotonic()
            if left <= 0:
                raise
            log.warning("hardware not reachable (%s); trying again in %.0f s", err, min(delay, left))
            if stop.wait(min(delay, left)):
                return None
            delay = min(2 * delay, WAIT_MAX_S)


def start_console(
    config: DaemonConfig, running: RunningDaemon, listener: socket.socket | None = None
) -> ConsoleServer | None:
    """The browser console when configured (``--http`` or ``[http]``), else None; shows the
    frames the daemon locates parts in, or else the embedded simulator's camera when it serves
    one (``--sim-arg=--camera-http=0``): never a second decode of the daemon's own stream
    (it cost ~30 % of a core, 2048 px frames at 15 frames/s)."""
    if config.http is None:
        return None
    try:
        from feeder.web import server
    except ImportError as err:
        raise InputError(
            "--http", f"the console needs Starlette and uvicorn ({err}): pip install feeder[http]"
        ) from None
    camera_http = running.links.describe().get("simulator_endpoints", {}).get("camera_http")
    if uses_camera(config):
        camera_http = None  # the console shows the daemon's own frames (Daemon.latest_image)
    return server.start_console(
        running.daemon,
        config.http,
        config.state_dir,
        None if camera_http is None else camera_http + "/video.mjpg",
        listener,
    )
