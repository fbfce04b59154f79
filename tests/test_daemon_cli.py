"""``feeder move|status|stop|calibrate|history|shutdown`` against the daemon on the fake world:
exit codes 0 done, 1 refused/failed, 2 bad input, 3 unreachable or silent; lengths with units;
a light start (no numpy for ``--help`` and ``status``)."""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_client import ScriptedServer
from test_daemon_service import start, wait_for

from feeder import Client
from feeder.cli import COMMANDS, build_parser, main
from feeder.cli.arguments import length_m
from feeder.daemon.service import Daemon

pytestmark = pytest.mark.timeout(60)

TESTS = Path(__file__).resolve().parent


@pytest.fixture
def daemon(short_dir: Path) -> Iterator[tuple[Daemon, str]]:
    running, _ = start(short_dir)
    yield running, str(short_dir / "run" / "f.sock")
    running.shutdown()


def test_move_absolute_and_relative_with_units_then_history(daemon, capsys) -> None:
    _, sock = daemon
    assert main(["move", "150um", "--socket", sock, "--json"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["target_m"] == 150e-6  # JSON stays SI, exactly
    assert first["status"] == "done" and abs(first["error_m"]) <= 1e-6
    assert main(["move", "--by", "-50µm", "--socket", sock, "--json"]) == 0
    second = json.loads(capsys.readouterr().out)
    # relative to the latest sensor frame (noise 0.05 µm), not to the averaged reached position
    assert second["target_m"] == pytest.approx(first["reached_m"] - 50e-6, abs=0.5e-6)
    assert main(["move", "--by=-0.02mm", "--socket", sock, "--json"]) == 0
    third = json.loads(capsys.readouterr().out)
    assert third["target_m"] == pytest.approx(second["reached_m"] - 20e-6, abs=0.5e-6)
    assert main(["move", "--socket", sock, "--json", "--", "-100um"]) == 0
    assert json.loads(capsys.readouterr().out)["target_m"] == -100e-6
    assert main(["move", "-2e-5", "--socket", sock]) == 0  # no "--": still a value
    assert "for target -20.000 µm" in capsys.readouterr().out
    assert main(["history", "--socket", sock, "--json"]) == 0
    moves = json.loads(capsys.readouterr().out)["moves"]
    assert [m["status"] for m in moves] == ["done"] * 5
    assert [m["target_m"] for m in moves][::3] == [150e-6, -100e-6]
    assert main(["status", "--socket", sock]) == 0
    text = capsys.readouterr().out
    assert "state: idle" in text and "step coarse/forward" in text and "loop: 100 Hz" in text


def test_pose_options_parse_negative_values_and_a_one_axis_daemon_takes_x_only(daemon, capsys) -> None:
    _, sock = daemon
    assert main(["move", "--x", "-40um", "--socket", sock, "--json"]) == 0  # x alone: a move along x
    assert json.loads(capsys.readouterr().out)["target_m"] == -40e-6
    assert main(["move", "--x=-30um", "--angle", "-5deg", "--socket", sock]) == 1
    assert "drives one axis (x)" in capsys.readouterr().err
    assert main(["move", "--y", "10um", "--part", "2", "--socket", sock]) == 1
    assert "refused" in capsys.readouterr().err
    assert main(["move", "150um", "--x", "1mm", "--socket", sock]) == 2
    assert "--x/--y/--angle" in capsys.readouterr().err
    for where in (["--", "-100um"], ["--by", "20um"]):  # moved part 1 when part 2 was asked for
        assert main(["move", "--part", "2", "--socket", sock, *where]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("feeder move: error: --part: TARGET_M and --by")
    with pytest.raises(SystemExit) as bad:
        main(["move", "--angle", "15 parsecs", "--socket", sock])
    assert bad.value.code == 2 and "expected an angle like 15deg" in capsys.readouterr().err


def test_exit_codes_0_1_2_3(daemon, short_dir: Path, capsys) -> None:
    _, sock = daemon
    assert main(["status", "--socket", sock, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["state"] == "idle"
    # 1: refused, with the daemon's reason on one line
    assert main(["move", "1.0", "--socket", sock]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1
    assert captured.err.startswith("feeder move: refused: ") and "travel limits" in captured.err
    # 2: bad input, named
    assert main(["move", "--socket", sock]) == 2
    assert "TARGET_M" in capsys.readouterr().err
    with pytest.raises(SystemExit) as bad_unit:
        main(["move", "--by", "5furlongs", "--socket", sock])
    assert bad_unit.value.code == 2
    assert "argument --by: expected a length" in capsys.readouterr().err
    with pytest.raises(SystemExit) as bad_timeout:
        main(["status", "--timeout", "0", "--socket", sock])
    assert bad_timeout.value.code == 2
    assert main(["calibrate", "--steps", "1", "--socket", sock]) == 2
    # 3: nobody there
    assert main(["status", "--socket", str(short_dir / "none" / "x.sock")]) == 3
    assert "daemon unreachable: no daemon socket" in capsys.readouterr().err
    assert main(["move", "10um", "--socket", str(short_dir / "none" / "x.sock")]) == 3


def test_a_stopped_move_exits_1_with_its_result(daemon, capsys) -> None:
    _, sock = daemon
    codes: list[int] = []
    mover = threading.Thread(target=lambda: codes.append(main(["move", "900um", "--socket", sock])))
    mover.start()
    with Client(sock) as client:
        wait_for(lambda: client.status().state == "moving")
        assert main(["move", "0um", "--queue", "--no-wait", "--socket", sock]) == 0
        assert capsys.readouterr().out == "move accepted (queue position 1)\n"
        assert main(["stop", "--socket", sock, "--json"]) == 0
        mover.join(10)
        out = capsys.readouterr().out
        assert codes == [1]
        (move_line,) = [line for line in out.splitlines() if line.startswith("move ")]
        stop_json = "\n".join(line for line in out.splitlines() if line != move_line)
        assert json.loads(stop_json) == {"stopped": True, "dequeued": 1}
        assert move_line.startswith("move stopped: ") and "for target 900.000 µm" in move_line
        wait_for(lambda: client.status().state == "idle")
    assert main(["history", "--socket", sock, "--json"]) == 0
    (record,) = json.loads(capsys.readouterr().out)["moves"]
    assert record["status"] == "stopped" and record["target_m"] == 900e-6


def test_stop_with_nothing_moving_and_calibrate(daemon, capsys) -> None:
    _, sock = daemon
    assert main(["stop", "--socket", sock, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["stopped"] is False
    assert main(["stop", "--socket", sock]) == 0
    assert capsys.readouterr().out == "nothing was moving\n"
    assert main(["calibrate", "--steps", "8", "--socket", sock, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["kind"] == "calibrate" and result["status"] == "done"
    assert result["estimates"]["coarse/forward"]["steps"] >= 8


def test_a_refused_stop_or_failed_move_says_why(short_dir: Path, capsys) -> None:
    """Never "nothing was moving" after a refusal; a failed move prints its result, exit 1."""
    path = short_dir / "s.sock"
    replies = {
        "stop": {"ok": False, "error": "amplifier lost; reconnecting"},
        "move": {
            "ok": False,
            "error": "amplifier lost: no answer",
            "result": {
                "kind": "move",
                "status": "fault",
                "reason": "amplifier lost: no answer",
                "target_m": 1e-4,
                "start_m": 0.0,
                "reached_m": 2e-5,
                "error_m": -8e-5,
                "steps": 9,
                "bursts": 1,
                "duration_s": 0.2,
                "estimates": {},
                "move_id": 4,
            },
        },
    }
    server = ScriptedServer(path, lambda request, conn: replies[request["cmd"]])
    try:
        assert main(["stop", "--socket", str(path)]) == 1
        captured = capsys.readouterr()
        assert "nothing was moving" not in captured.out + captured.err
        assert captured.err == "feeder stop: refused: amplifier lost; reconnecting\n"
        assert main(["move", "100um", "--socket", str(path)]) == 1
        assert capsys.readouterr().out.startswith("move fault: amplifier lost: no answer; reached")
        assert main(["move", "100um", "--socket", str(path), "--json"]) == 1
        assert json.loads(capsys.readouterr().out)["move_id"] == 4
    finally:
        server.close()


def test_shutdown(daemon, capsys) -> None:
    running, sock = daemon
    assert main(["shutdown", "--socket", sock]) == 0
    assert capsys.readouterr().out == "the daemon stopped\n"
    assert running.wait(5) and not Path(sock).exists()  # the store closes after the socket
    assert main(["shutdown", "--socket", sock]) == 3


def test_lengths_with_units() -> None:
    cases = {
        "150um": 150e-6,
        "150µm": 150e-6,
        "150μm": 150e-6,
        "1.2mm": 1.2e-3,
        "3e-4": 3e-4,
        "-100um": -100e-6,
        "-20 nm": -20e-9,
        "+.5mm": 0.5e-3,
        "2m": 2.0,
        "-1e-4": -1e-4,
        " 7.5e2nm ": 750e-9,
        "0um": 0.0,
    }
    assert {text: length_m(text) for text in cases} == cases
    for bad in (
        "",
        "um",
        "1 furlong",
        "1 um um",
        "nan",
        "inf",
        "1e999",
        "1e99999999999mm",
        "--5um",
        "1,5mm",
        "5 UM",
    ):
        with pytest.raises(argparse.ArgumentTypeError, match="length"):
            length_m(bad)


# -- a daemon in its own process: SIGSTOP must not hang the CLI -------------------------

DAEMON_PROCESS = """
import dataclasses, sys
from pathlib import Path
sys.path.insert(0, sys.argv[2])
from test_daemon_service import FakeLinks, make_setup
from test_control_loop import TRUE
from test_daemon_doubles import FakeWorld
from feeder.daemon.service import Daemon
setup = make_setup(Path(sys.argv[1]))
slow = {k: dataclasses.replace(m, settings=dataclasses.replace(m.settings, frequency_hz=100.0))
        for k, m in setup.modes.items()}        # 100 steps/s: a 900 µm move lasts seconds
daemon = Daemon(FakeLinks(FakeWorld(TRUE, seed=5)), dataclasses.replace(setup, modes=slow))
daemon.start()
print("ready", flush=True)
daemon.wait()
"""


def _feeder(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "feeder", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def test_a_stopped_daemon_exits_3_within_the_timeout(short_dir: Path, capsys) -> None:
    daemon = subprocess.Popen(
        [sys.executable, "-c", DAEMON_PROCESS, str(short_dir), str(TESTS)], stdout=subprocess.PIPE, text=True
    )
    sock = str(short_dir / "run" / "f.sock")
    try:
        assert daemon.stdout is not None and daemon.stdout.readline() == "ready\n"
        mover = _feeder("move", "900um", "--timeout", "1", "--socket", sock)
        with Client(sock) as client:
            deadline = time.monotonic() + 20
            while client.status().state != "moving":
                assert time.monotonic() < deadline and mover.poll() is None
                time.sleep(0.02)
            os.kill(daemon.pid, signal.SIGSTOP)
            stopped_at = time.monotonic()
            _, err = mover.communicate(timeout=10)
            move_exit_s = time.monotonic() - stopped_at
            began = time.monotonic()  # in this process: a loaded machine's start-up not counted
            status_code = main(["status", "--timeout", "1", "--socket", sock])
            status_exit_s = time.monotonic() - began
            os.kill(daemon.pid, signal.SIGCONT)
            assert client.status(timeout_s=10).state in ("moving", "idle")  # alive again
        assert mover.returncode == 3, err
        assert "did not answer 'status (heartbeat)' within 1 s" in err
        assert move_exit_s <= 1 + 1  # --timeout + 1 s
        assert status_code == 3 and "did not answer 'status' within 1 s" in capsys.readouterr().err
        assert status_exit_s <= 1 + 1
        shutdown = _feeder("shutdown", "--timeout", "30", "--socket", sock)
        out, err = shutdown.communicate(timeout=30)
        assert (shutdown.returncode, out) == (0, "the daemon stopped\n"), err
        assert daemon.wait(timeout=10) == 0
    finally:
        os.kill(daemon.pid, signal.SIGCONT) if daemon.poll() is None else None
        daemon.kill()
        daemon.wait()


# -- start-up: registering the parsers loads nothing heavy -------------------------------

LIGHT_START = """
import sys
from feeder.cli import build_parser, main
build_parser([])
try:
    main(["--help"])
except SystemExit as done:
    assert done.code == 0
assert main(["status", "--socket", sys.argv[1]]) == 3
heavy = sorted(m for m in ("numpy", "scipy", "control", "matplotlib", "serial", "can")
               if m in sys.modules)
print(" ".join(heavy) or "light")
"""


def test_help_and_status_import_nothing_heavy(short_dir: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-c", LIGHT_START, str(short_dir / "none.sock")],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert out.splitlines()[-1] == "light"


DESIGN_HELP = """
import sys
from feeder.cli import main
for command in ("waveform", "simulate", "plan"):
    try:
        main([command, "--help"])
    except SystemExit as done:
        assert done.code == 0
import firmware_sim.options
print(" ".join(m for m in ("control", "scipy.signal", "matplotlib") if m in sys.modules) or "light")
"""


def test_the_design_commands_help_loads_no_lti_toolbox() -> None:
    """``feeder waveform|simulate|plan --help`` and firmware_sim's options name a stack but build
    no model: python-control and scipy.signal (~2 s of the 3 s these took) stay unloaded."""
    out = subprocess.run([sys.executable, "-c", DESIGN_HELP], capture_output=True, text=True, check=True)
    assert out.stdout.splitlines()[-1] == "light"


def test_the_lazy_parser_is_the_full_parser() -> None:
    """Placeholders carry the real help lines; loading one command leaves the others' alone."""
    full = build_parser()
    (sub,) = [a for a in full._actions if isinstance(a, type(full._subparsers._group_actions[0]))]
    assert {c.dest: c.help for c in sub._choices_actions} == {k: h for k, (_, h) in COMMANDS.items()}
    assert build_parser([]).format_help() == full.format_help()
    for name, parser in sub.choices.items():
        lazy = build_parser([name])
        (lazy_sub,) = [a for a in lazy._actions if a.dest == "command"]
        assert lazy_sub.choices[name].format_help() == parser.format_help(), name


def test_pose_moves_no_wait_one_turn_and_release(short_dir: Path, capsys) -> None:
    """A pose move may return once accepted; an angle beyond one turn is bad input (exit 2, nothing
    sent); `release` names what it let go."""
    path = short_dir / "s.sock"
    asked: list[dict[str, Any]] = []

    def answer(request: dict[str, Any], conn: Any) -> dict[str, Any]:
        asked.append(request)
        if request["cmd"] == "release":
            return {"ok": True, "released": [] if request.get("part") == 3 else [1, 2]}
        return {"ok": True, "accepted": True, "queue_position": 0}

    server = ScriptedServer(path, answer)
    try:
        assert main(["move", "--x", "1mm", "--angle", "30deg", "--no-wait", "--socket", str(path)]) == 0
        assert asked[-1]["wait"] is False and asked[-1]["angle_rad"] == pytest.approx(math.radians(30))
        sent = len(asked)
        assert main(["move", "--angle", "400deg", "--socket", str(path)]) == 2
        assert "--angle: must lie within ±360° (one turn), got 400°" in capsys.readouterr().err
        assert len(asked) == sent  # refused before anything reached the daemon
        assert main(["release", "--socket", str(path)]) == 0
        assert capsys.readouterr().out == "released part 1, 2\n" and "part" not in asked[-1]
        assert main(["release", "--part", "3", "--socket", str(path), "--json"]) == 0
        assert json.loads(capsys.readouterr().out) == {"released": []} and asked[-1]["part"] == 3
    finally:
        server.close()


def test_status_prints_the_daemons_warnings(daemon, short_dir: Path, capsys) -> None:
    """``stack_warning`` (hardware without ``[stack]``) is printed as the noise warning is."""
    _, socket_path = daemon
    with Client(socket_path) as client:
        reply = dict(client.status().raw)
    reply["stack_warning"] = "no [stack] in the configuration: state yours"
    path = short_dir / "w.sock"
    server = ScriptedServer(path, lambda request, conn: reply)
    try:
        assert main(["status", "--socket", str(path)]) == 0
        assert "warning: no [stack] in the configuration: state yours\n" in capsys.readouterr().out
    finally:
        server.close()
