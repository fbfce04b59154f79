"""The daemon drives what a lab owns: only a real ANC300's verbs, and a stop that tells the truth.

A proxy between the daemon and firmware_sim's TCP console forwards only the
ANC300's real verb set (:data:`feeder.protocol.anc300.REAL_VERBS`) and answers
anything else the way an ANC300 does; the daemon must complete its moves
through it without a single refusal.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from pathlib import Path

import pytest
import serial
from listener import Listener
from test_daemon_hil import (  # noqa: F401
    TRANSPORTS,
    DaemonProcess,
    assert_within_tolerance,
    base,
    true_coarse_steps,
)

from feeder.daemon.config import DaemonConfig, embedded_plane
from feeder.daemon.launcher import Simulator
from feeder.daemon.links import simulator_args
from feeder.protocol.anc300 import MOVE_PATH, REAL_VERBS, UNKNOWN_COMMAND, VERBS

pytestmark = pytest.mark.timeout(180)


class Anc300Proxy:
    """TCP relay to a console that lets only the ANC300's real verbs through.

    Lines before ``Authorization success`` are the login and pass unchanged.
    ``forwarded`` counts the verbs sent on; ``refused`` lists the lines answered
    with the ANC300's error reply instead.
    """

    def __init__(self, upstream_url: str) -> None:
        host, _, port = upstream_url.removeprefix("socket://").rpartition(":")
        self.upstream = (host, int(port))
        self.forwarded: dict[str, int] = {}
        self.refused: list[str] = []
        self._lock = threading.Lock()
        self._listener = Listener(socket.create_server(("127.0.0.1", 0)), self._accepted)
        self.url = f"socket://127.0.0.1:{self._listener.port}"

    def _accepted(self, client: socket.socket) -> None:
        up = socket.create_connection(self.upstream)
        logged_in = threading.Event()
        threading.Thread(target=self._down, args=(up, client, logged_in), daemon=True).start()
        threading.Thread(target=self._up, args=(client, up, logged_in), daemon=True).start()

    @staticmethod
    def _down(up: socket.socket, client: socket.socket, logged_in: threading.Event) -> None:
        seen = b""
        with contextlib.suppress(OSError):
            while data := up.recv(65536):
                if not logged_in.is_set():
                    seen += data
                    if b"Authorization success" in seen:
                        logged_in.set()
                client.sendall(data)
        with contextlib.suppress(OSError):
            client.shutdown(socket.SHUT_RDWR)

    def _up(self, client: socket.socket, up: socket.socket, logged_in: threading.Event) -> None:
        buffer = b""
        with contextlib.suppress(OSError):
            while data := client.recv(65536):
                buffer += data
                while b"\n" in buffer:
                    line, buffer = buffer.split(b"\n", 1)
                    self._line(line + b"\n", client, up, logged_in)
        with contextlib.suppress(OSError):
            up.shutdown(socket.SHUT_RDWR)

    def _line(self, raw: bytes, client: socket.socket, up: socket.socket, logged_in: threading.Event) -> None:
        if not logged_in.is_set():
            logged_in.wait(0.5)  # the password line and the greeting race
        words = raw.decode("ascii", "replace").split()
        if not logged_in.is_set() or not words:
            up.sendall(raw)
            return
        verb = words[0].lower()
        with self._lock:
            if verb in REAL_VERBS:
                self.forwarded[verb] = self.forwarded.get(verb, 0) + 1
            else:
                self.refused.append(raw.decode("ascii", "replace").strip())
        if verb in REAL_VERBS:
            up.sendall(raw)
        else:
            client.sendall(f"{UNKNOWN_COMMAND}\r\nERROR\r\n".encode())

    def close(self) -> None:
        self._listener.close()


def test_three_moves_through_a_proxy_that_passes_only_real_anc300_verbs(base: Path) -> None:  # noqa: F811
    # a simulator rated like an ANC300 (150 V, 10 kHz) with every extension still on offer:
    # the proxy, not the simulator, is what keeps the daemon honest
    sim = Simulator(
        [
            "--console",
            "tcp:127.0.0.1:0",
            "--sensor",
            "tcp:127.0.0.1:0",
            "--dialect",
            "extended",
            "--v-max",
            "150",
            "--max-frequency-hz",
            "10000",
            "--tau-offset=0.15",
            "--seed=6",
        ]
    )
    proxy = Anc300Proxy(sim.endpoints["console_tcp"])
    try:
        config = base / "feeder.toml"
        config.write_text(
            f'[amplifier]\nport = "{proxy.url}"\nmodel = "anc300"\n'
            f'[sensor]\naddress = "{sim.endpoints["sensor_tcp"]}"\n'
        )
        daemon = DaemonProcess(base, f"--config={config}")
        try:
            replies = [daemon.request("move", target_m=t) for t in (150e-6, -60e-6, 25e-6)]
            tolerance = daemon.request("status")["tolerance_m"]
        finally:
            assert daemon.stop() == 0
    finally:
        proxy.close()
        sim.stop()
    assert_within_tolerance(replies, tolerance)
    assert "move done" in (base / "state" / "daemon.log").read_text()
    assert proxy.refused == []
    assert set(proxy.forwarded) <= MOVE_PATH
    assert {"setpu", "setpd", "stepu", "stepd", "stepw", "setm"} <= set(proxy.forwarded)


@pytest.mark.parametrize("transport", [t for t in TRANSPORTS if t != "serial"])
def test_the_same_moves_over_can(base: Path, transport: str) -> None:  # noqa: F811
    daemon = DaemonProcess(base, f"--transport={transport}")
    try:
        replies = [daemon.request("move", target_m=t) for t in (150e-6, -60e-6, 25e-6)]
        tolerance = daemon.request("status")["tolerance_m"]
    finally:
        assert daemon.stop() == 0
    assert_within_tolerance(replies, tolerance)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_stop_mid_burst_records_where_the_part_settled(base: Path, transport: str) -> None:  # noqa: F811
    config = base / "feeder.toml"  # one long burst: the stop lands in the middle of it
    config.write_text("[control]\nmax_burst_steps = 4000\n")
    daemon = DaemonProcess(base, f"--transport={transport}", f"--config={config}")
    try:
        assert daemon.request("move", target_m=4e-3, wait=False)["ok"]
        daemon.wait_for(lambda s: (s["position_m"] or 0) > 150e-6)
        assert daemon.request("stop")["stopped"] is True
        idle = daemon.wait_for(lambda s: s["state"] == "idle", timeout=10)
        time.sleep(1.0)
        later = daemon.request("status")
        move = daemon.request("history", limit=1)["moves"][-1]
        coarse_step = true_coarse_steps(daemon, later)[0]  # the plant's true step
    finally:
        assert daemon.stop() == 0
    tolerance = later["tolerance_m"]
    assert move["status"] == "stopped"
    assert idle["last_result"]["status"] == "stopped"
    assert abs(move["reached_m"] - later["position_m"]) <= tolerance, (move, later["position_m"])
    assert abs(idle["position_m"] - later["position_m"]) <= tolerance
    # the steps recorded are the ones played: with the plant's true step they account for
    # the distance travelled (a burst from rest loses less than a step of hundreds)
    travelled = move["reached_m"] - (move["start_m"] or 0.0)
    assert move["steps"] > 50
    # CANopen reads the drive's counter; an ANC300 counts nothing, so the host estimates the
    # steps of a cut burst from when its stepu and stop reached the unit: the scheduling
    # noise of both ends × f (a ms is 3 steps at 3 kHz).  Measured 2026-11-28 (steps × true
    # step over the distance): 0.93-1.00 quiet, 0.96-1.05 with two CPU hogs; from the round
    # trips' midpoints before, 0.90-0.95, 0.82-0.92, and 0.73 once in a parallel CI run
    # (docs/daemon.md, *What the serial path sends*)
    assert move["steps"] * coarse_step == pytest.approx(travelled, rel=0.08 if transport == "can" else 0.15)
    # counted where the drive counts them (CANopen), estimated from time where it cannot (ANC300)
    assert move["steps_estimated"] is (transport == "serial")


def test_strict_dialect_answers_every_extension_as_an_anc300() -> None:
    sim = Simulator(["--console", "pty", "--dialect", "anc300"])
    try:
        port = serial.serial_for_url(sim.endpoints["console_pty"], timeout=2.0)
        try:
            port.write(b"echo off\r\n")
            assert port.read_until(b"OK\r\n").endswith(b"OK\r\n")
            for verb in VERBS:
                line = f"{verb.name} 1" if verb.axis else verb.name
                port.write(line.encode() + b"\r\n")
                reply = port.read_until(b"ERROR\r\n" if not verb.real else b"\r\n").decode()
                if verb.real:
                    assert UNKNOWN_COMMAND not in reply, (verb.name, reply)
                    port.reset_input_buffer()
                    port.write(b"stop 1\r\n")  # resynchronise on a short reply
                    time.sleep(0.05)
                    port.reset_input_buffer()
                else:
                    assert reply == f"{UNKNOWN_COMMAND}\r\nERROR\r\n", (verb.name, reply)
        finally:
            port.close()
    finally:
        sim.stop()


def test_the_embedded_plane_streams_no_true_positions() -> None:
    """The plane's daemon sees its parts through the simulator's camera, as on hardware: the
    simulator is not asked for its stream of the true positions (the line's position sensor)."""
    assert "--sensor" not in simulator_args(embedded_plane(DaemonConfig()))
    line = simulator_args(DaemonConfig())
    assert line[line.index("--sensor") + 1] == "tcp:127.0.0.1:0"


def test_the_embedded_default_runs_the_strict_dialect() -> None:
    args = simulator_args(DaemonConfig())
    assert args[args.index("--dialect") + 1] == "anc300"
    assert DaemonConfig().amplifier.model == "anc300"
    v_max = float(args[args.index("--v-max") + 1])
    assert v_max == 150.0
