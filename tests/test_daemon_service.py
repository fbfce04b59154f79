"""The daemon service over its Unix socket, with the in-process fake world as hardware."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
from test_control_loop import MODES, SETTINGS, TRUE
from test_daemon_doubles import FakeAmplifier, FakeSensor, FakeWorld

from feeder.daemon.client import Client, DaemonUnavailable
from feeder.daemon.client_connection import MAX_LINE_BYTES
from feeder.daemon.config import CameraConfig
from feeder.daemon.service import Daemon, DaemonSetup
from feeder.daemon.socket_server import bind_socket
from feeder.daemon.store import Store
from feeder.drivers.amplifier import AmplifierLinkLost
from feeder.errors import InputError
from feeder.vision.calibration import CameraCalibration

pytestmark = pytest.mark.timeout(60)


class FakeLinks:
    def __init__(self, world: FakeWorld) -> None:
        self.world = world
        self.amplifier_up = True
        self.amplifiers: list[FakeAmplifier] = []
        self.sensors: list[FakeSensor] = []
        self.configured: CameraCalibration | None = None  # a camera's, as DriverLinks makes it
        self.calibrations: list[CameraCalibration | None] = []  # what each sensor locates with
        self.frames_paused = False  # sensors opened (a reconnect's too) deliver no frame

    def open_amplifier(self) -> FakeAmplifier:
        if not self.amplifier_up:
            raise AmplifierLinkLost("fake: no answer")
        amp = FakeAmplifier(self.world)
        self.amplifiers.append(amp)
        return amp

    def open_sensor(self, calibration: CameraCalibration | None = None) -> FakeSensor:
        sensor = FakeSensor(self.world)
        sensor.paused = self.frames_paused
        self.sensors.append(sensor)
        self.calibrations.append(calibration)
        return sensor

    def configured_calibration(self) -> CameraCalibration | None:
        return self.configured


def make_setup(base: Path) -> DaemonSetup:
    return DaemonSetup(
        modes=MODES,
        loop=SETTINGS,
        database_path=base / "state" / "f.sqlite",
        socket_path=base / "run" / "f.sock",
        calibration_key="test",
        info={"transport": "fake"},
    )


def start(base: Path, world: FakeWorld | None = None) -> tuple[Daemon, FakeLinks]:
    world = world or FakeWorld(TRUE, scatter=0.03, noise_m=0.05e-6, seed=3)
    links = FakeLinks(world)
    daemon = Daemon(links, make_setup(base))
    daemon.start()
    return daemon, links


def wait_for(predicate, timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < end, "condition not reached in time"
        time.sleep(0.01)


def test_socket_is_owner_only_and_a_move_is_recorded(short_dir: Path) -> None:
    daemon, links = start(short_dir)
    try:
        sock = short_dir / "run" / "f.sock"
        assert oct(sock.stat().st_mode & 0o777) == "0o600"
        assert oct(sock.parent.stat().st_mode & 0o777) == "0o700"
        with Client(sock) as client:
            reply = client.request("move", target_m=120e-6)
            assert reply["ok"], reply
            assert abs(reply["result"]["error_m"]) <= 1e-6
            status = client.request("status")
            history = client.request("history")
    finally:
        daemon.shutdown()
    assert status["state"] == "idle" and status["position_state"] == "confirmed"
    assert status["timing"]["ticks"] > 0
    (move,) = history["moves"]
    assert move["status"] == "done" and move["target_m"] == 120e-6
    assert move["steps"] == reply["result"]["steps"] > 0
    assert not sock.exists()
    assert links.amplifiers[0].grounded  # grounded on shutdown


def test_bad_requests_are_refused_and_the_daemon_keeps_running(short_dir: Path) -> None:
    daemon, _ = start(short_dir)
    sock_path = short_dir / "run" / "f.sock"
    try:
        with Client(sock_path) as client:
            assert client.request("move", target_m=20e-6)["ok"]
        raw = socket.socket(socket.AF_UNIX)
        raw.connect(str(sock_path))
        f = raw.makefile("rb")
        replies = []
        for line in (
            b"{not json\n",
            b"[1, 2]\n",
            b'{"cmd": "fly"}\n',
            b"\xff\xfe\n",
            b'{"cmd": "move", "target_m": "far"}\n',
            b'{"cmd": "move", "target_m": 1e9}\n',
            b'{"cmd": "move", "target_m": NaN}\n',
            b'{"cmd": "move"}\n',
        ):
            raw.sendall(line)
            replies.append(json.loads(f.readline()))
        assert all(r["ok"] is False and r["error"] for r in replies)
        assert "travel limits" in replies[5]["error"]
        raw.sendall(b"x" * (MAX_LINE_BYTES + 10))
        last = json.loads(f.readline())
        assert "longer than" in last["error"]
        assert f.readline() == b""  # connection closed
        raw.close()
        with Client(sock_path) as client:  # the daemon still answers
            status = client.request("status")
            history = client.request("history")
    finally:
        daemon.shutdown()
    assert status["ok"] and status["state"] == "idle"
    assert [m["target_m"] for m in history["moves"]] == [20e-6]
    store = Store(short_dir / "state" / "f.sqlite")
    assert store.integrity_ok() and len(store.moves()) == 1


def test_second_move_is_refused_or_queued(short_dir: Path) -> None:
    daemon, _ = start(short_dir)
    sock_path = short_dir / "run" / "f.sock"
    try:
        with Client(sock_path) as first, Client(sock_path) as second:
            assert first.request("move", target_m=600e-6, wait=False)["ok"]
            wait_for(lambda: second.request("status")["state"] == "moving")
            refused = second.request("move", target_m=0.0)
            queued = second.request("move", target_m=100e-6, queue=True)
            assert refused["ok"] is False and "in progress" in refused["error"]
            assert queued["ok"], queued
            history = second.request("history")["moves"]
    finally:
        daemon.shutdown()
    assert [m["target_m"] for m in history] == [600e-6, 100e-6]
    assert [m["status"] for m in history] == ["done", "done"]


def test_calibration_and_history_survive_a_restart(short_dir: Path) -> None:
    world = FakeWorld(TRUE, scatter=0.03, noise_m=0.05e-6, seed=4)
    daemon, _ = start(short_dir, world)
    try:
        with Client(short_dir / "run" / "f.sock") as client:
            cal = client.request("calibrate")
            assert cal["ok"], cal
            learned = client.request("status")["estimates"]
    finally:
        daemon.shutdown()
    assert learned["coarse/forward"]["step_m"] == pytest.approx(3.0e-6, rel=0.05)
    assert learned["coarse/backward"]["step_m"] == pytest.approx(2.6e-6, rel=0.05)
    again, _ = start(short_dir, world)
    try:
        with Client(short_dir / "run" / "f.sock") as client:
            restored = client.request("status")["estimates"]
    finally:
        again.shutdown()
    assert restored == learned


def test_killed_mid_move_restarts_uncertain_until_the_sensor_confirms(short_dir: Path) -> None:
    setup = make_setup(short_dir)
    store = Store(setup.database_path)
    store.save_position(42e-6)
    running = store.begin_move(300e-6, 42e-6)  # what a SIGKILL mid-move leaves behind
    store.close()
    world = FakeWorld(TRUE, position_m=51e-6)
    links = FakeLinks(world)
    links.frames_paused = True  # the camera has not delivered a frame yet
    daemon = Daemon(links, setup)
    daemon.start()
    try:
        time.sleep(1.5)  # past the sensor's timeout: a reconnect's camera gives no frame either
        status = daemon.status()
        assert status["position_state"] == "uncertain" and status["position_m"] is None
        assert status["last_known_position_m"] == 42e-6
        assert status["interrupted_moves"] == [running]
        links.frames_paused = False
        for sensor in links.sensors:
            sensor.paused = False
        wait_for(lambda: daemon.status()["position_state"] == "confirmed")
        assert daemon.status()["position_m"] == pytest.approx(51e-6)
        history = daemon.handle({"cmd": "history"})["moves"]
    finally:
        daemon.shutdown()
    assert history[0]["status"] == "interrupted"


def test_amplifier_link_loss_faults_reconnects_and_does_not_resume(
    short_dir: Path, caplog: pytest.LogCaptureFixture
) -> None:
    daemon, links = start(short_dir)
    caplog.set_level("ERROR", logger="feeder.daemon.service")
    try:
        with Client(short_dir / "run" / "f.sock") as client:
            assert client.request("move", target_m=800e-6, wait=False)["ok"]
            wait_for(lambda: links.world.position(time.monotonic()) > 30e-6)
            links.amplifier_up = False
            links.amplifiers[0].link_up = False
            wait_for(lambda: client.request("status")["state"] == "fault")
            refused = client.request("move", target_m=0.0)
            time.sleep(0.5)  # a few failed reconnect attempts
            links.amplifier_up = True
            wait_for(lambda: client.request("status")["state"] == "idle")
            status = client.request("status")
            history = client.request("history")["moves"]
            time.sleep(0.2)
    finally:
        daemon.shutdown()
    assert refused["ok"] is False and "fault" in refused["error"]
    assert history[-1]["status"] == "fault"
    assert status["faults"][-1]["reconnected_after_attempts"] >= 2
    fresh = links.amplifiers[-1]
    assert "ground" in fresh.calls and "step" not in fresh.calls  # grounded, not resumed
    # the lost link could not ground: the log says so (it said "output grounded" regardless)
    (lost,) = [r.getMessage() for r in caplog.records if "amplifier link lost" in r.getMessage()][:1]
    assert "the output could not be grounded (x: fake link down)" in lost and "output grounded" not in lost


def test_refuses_socket_paths_of_other_users(short_dir: Path) -> None:
    open_dir = short_dir / "open"
    open_dir.mkdir()
    open_dir.chmod(0o777)
    with pytest.raises(InputError, match="writable by others"):
        bind_socket(open_dir / "f.sock")
    if os.getuid() != 0:
        pytest.skip("needs root to create files owned by another user")
    foreign = short_dir / "foreign"
    foreign.mkdir(mode=0o700)
    os.chown(foreign, 65534, 65534)
    with pytest.raises(InputError, match="owned by uid 65534"):
        bind_socket(foreign / "f.sock")
    mine = short_dir / "mine"
    mine.mkdir(mode=0o700)
    planted = socket.socket(socket.AF_UNIX)
    planted.bind(str(mine / "f.sock"))
    os.chown(mine / "f.sock", 65534, 65534)
    with pytest.raises(InputError, match="owned by uid 65534"):
        bind_socket(mine / "f.sock")
    with pytest.raises(DaemonUnavailable, match="owned by uid 65534"):
        Client(mine / "f.sock")
    planted.close()


def test_a_second_daemon_on_the_same_socket_is_refused(short_dir: Path) -> None:
    daemon, _ = start(short_dir)
    try:
        with pytest.raises(InputError, match="already listening"):
            bind_socket(short_dir / "run" / "f.sock")
    finally:
        daemon.shutdown()


def test_a_second_daemon_on_the_same_state_directory_is_refused(short_dir: Path) -> None:
    daemon, _ = start(short_dir)
    other = make_setup(short_dir)
    other = DaemonSetup(**{**other.__dict__, "socket_path": short_dir / "run" / "g.sock"})
    try:
        with pytest.raises(InputError, match="another daemon is using this state directory"):
            Daemon(FakeLinks(FakeWorld(TRUE)), other)
    finally:
        daemon.shutdown()
    again = Daemon(FakeLinks(FakeWorld(TRUE)), other)  # free once the first one is gone
    again.shutdown()


OTHER_USER_CONNECT = """
import os, socket, sys
os.setgid(65534); os.setuid(65534)
s = socket.socket(socket.AF_UNIX)
try:
    s.connect(sys.argv[1])
except PermissionError:
    print("EACCES"); sys.exit(0)
try:
    s.sendall(b'{"cmd": "status"}\\n')
except BrokenPipeError:
    pass                  # the daemon answered (refusal) and closed before our request
print(s.makefile().readline().strip())
"""


def test_other_users_cannot_use_the_socket(short_dir: Path) -> None:
    if os.getuid() != 0:
        pytest.skip("needs root to act as another user")
    daemon, _ = start(short_dir)
    sock = short_dir / "run" / "f.sock"
    try:
        short_dir.chmod(0o755)

        def as_nobody() -> str:
            done = subprocess.run(
                [sys.executable, "-c", OTHER_USER_CONNECT, str(sock)],
                capture_output=True,
                text=True,
                timeout=30,
            )
            return done.stdout.strip()

        sock.parent.chmod(0o755)
        blocked_by_mode = as_nobody()  # socket 0600: cannot connect at all
        sock.chmod(0o666)  # even if the mode were opened up ...
        answer = as_nobody()  # ... the peer's uid is checked
        sock.chmod(0o600)
        sock.parent.chmod(0o700)
        with Client(sock) as client:
            still = client.request("status")
    finally:
        daemon.shutdown()
    assert blocked_by_mode == "EACCES"
    assert json.loads(answer) == {"ok": False, "error": "permission denied: not the owner"}
    assert still["ok"]


CONFIGURED = CameraCalibration(2.7e-6, origin_x_px=1023.5, origin_y_px=1023.5)


def store_calibration(base: Path, **record: object) -> None:
    """What ``feeder vision calibrate --save-state`` stores, beside a daemon or before it starts."""
    (base / "state").mkdir(exist_ok=True)
    store = Store(base / "state" / "f.sqlite")
    try:
        store.save_camera_calibration(record)
    finally:
        store.close()


def test_the_stored_camera_calibration_is_what_parts_are_located_with(short_dir: Path) -> None:
    store_calibration(short_dir, pixel_size_m=1.1e-6, rotation_rad=0.3, mirrored=True, moves_residual_px=0.2)
    links = FakeLinks(FakeWorld(TRUE, scatter=0.03, noise_m=0.05e-6, seed=3))
    links.configured = CONFIGURED
    daemon = Daemon(links, make_setup(short_dir))
    daemon.start()
    try:
        # no θ turns were measured: the origin stays the configured one
        assert links.calibrations == [CameraCalibration(1.1e-6, 0.3, True, 1023.5, 1023.5)]
        status = daemon.handle({"cmd": "status"})["camera_calibration"]
        assert status["source"] == "stored" and status["pixel_size_m"] == 1.1e-6 and status["mirrored"]
        assert status["moves_residual_px"] == 0.2  # the report's figures come along
        # calibrated again while the daemon runs: the next move locates with it
        time.sleep(0.01)  # a new updated_s
        store_calibration(short_dir, pixel_size_m=1.2e-6, rotation_rad=-0.1, mirrored=False,
                          origin_x_px=1000.0, origin_y_px=990.0)  # fmt: skip
        assert len(links.sensors) == 1
        reply = daemon.handle({"cmd": "move", "target_m": 120e-6})
        assert reply["ok"], reply
        assert links.calibrations[-1] == CameraCalibration(1.2e-6, -0.1, False, 1000.0, 990.0)
        assert len(links.sensors) == 2 and links.sensors[0].closed
        assert daemon.handle({"cmd": "status"})["camera_calibration"]["origin_y_px"] == 990.0
        assert daemon.handle({"cmd": "move", "target_m": 150e-6})["ok"]
        assert len(links.sensors) == 2  # nothing new stored: the same camera link
    finally:
        daemon.shutdown()


def test_a_camera_nobody_calibrated_refuses_moves_until_a_calibration_is_stored(short_dir: Path) -> None:
    """The configured calibration assumes the image is neither turned nor mirrored; a camera
    looking down on a plate sees it mirrored, so y and θ would come out with the wrong sign and
    the planner would steer the wrong way (and learn that).  ``[camera] aligned = true`` says
    the configured one is right (tests/test_daemon_hil.py); the simulator's camera needs none."""
    reason = CameraConfig(address="0").uncalibrated()
    assert reason is not None and "feeder vision calibrate-moves" in reason and "aligned" in reason
    assert (
        CameraConfig().uncalibrated() is None
        and CameraConfig(address="0", aligned=True).uncalibrated() is None
    )
    links = FakeLinks(FakeWorld(TRUE, scatter=0.03, noise_m=0.05e-6, seed=3))
    links.configured = CONFIGURED
    daemon = Daemon(links, replace(make_setup(short_dir), uncalibrated_camera=reason))
    daemon.start()
    try:
        assert daemon.handle({"cmd": "status"})["moves_refused"] == reason  # said before any move
        reply = daemon.handle({"cmd": "move", "target_m": 120e-6})
        assert not reply["ok"] and "is not calibrated" in reply["error"], reply
        assert daemon.handle({"cmd": "history"})["moves"] == []  # nothing was played
        # a scale from --image alone measured no turn or mirroring: still refused
        store_calibration(short_dir, pixel_size_m=2.7e-6, rotation_rad=0.0, mirrored=False)
        reply = daemon.handle({"cmd": "move", "target_m": 120e-6})
        assert not reply["ok"] and "measured no plate moves" in reply["error"], reply
        time.sleep(0.01)  # a new updated_s
        measured = {"rotation_rad": 0.0, "mirrored": False, "moves_residual_px": 0.1}
        store_calibration(short_dir, pixel_size_m=2.7e-6, **measured)
        reply = daemon.handle({"cmd": "move", "target_m": 120e-6})
        assert reply["ok"], reply
        assert daemon.handle({"cmd": "status"})["moves_refused"] is None
    finally:
        daemon.shutdown()


def test_without_a_camera_a_stored_calibration_is_not_used(short_dir: Path) -> None:
    store_calibration(short_dir, pixel_size_m=1.1e-6)
    daemon, links = start(short_dir)
    try:
        assert links.calibrations == [None]
        assert daemon.handle({"cmd": "status"})["camera_calibration"] is None
    finally:
        daemon.shutdown()


def test_a_broken_stored_calibration_is_refused_naming_its_field(short_dir: Path) -> None:
    store_calibration(short_dir, pixel_size_m=-1.0, rotation_rad=0.3)
    links = FakeLinks(FakeWorld(TRUE, seed=3))
    links.configured = CONFIGURED
    with pytest.raises(InputError, match=r"^the stored camera calibration\.pixel_size_m: must be a positive"):
        Daemon(links, make_setup(short_dir))
    store_calibration(short_dir, pixel_size_m=1e-6, mirrored="yes")
    with pytest.raises(InputError, match=r"calibration\.mirrored: not a valid value: 'yes'"):
        Daemon(links, make_setup(short_dir))


def test_a_stored_calibration_the_travel_does_not_fit_is_named_as_the_cause(short_dir: Path) -> None:
    """The camera refuses a travel it does not see whole (DriverLinks.open_sensor); with a stored
    calibration the start says where that came from and what to do."""

    class Unseeing(FakeLinks):
        def open_sensor(self, calibration: CameraCalibration | None = None) -> FakeSensor:
            if calibration is not None:
                raise InputError("travel", "the travel reaches beyond what the camera sees")
            return super().open_sensor(calibration)

    store_calibration(short_dir, pixel_size_m=1e-6)
    links = Unseeing(FakeWorld(TRUE, seed=3))
    links.configured = CONFIGURED
    with pytest.raises(InputError) as refused:
        Daemon(links, make_setup(short_dir))
    assert str(refused.value) == (
        "the stored camera calibration: travel: the travel reaches beyond what the camera sees (stored by "
        "`feeder vision calibrate[-moves] --save-state`: calibrate again, or narrow the travel in [control])"
    )


def test_status_says_moves_are_refused_while_the_store_cannot_be_written(short_dir: Path) -> None:
    """``moves_refused`` was null while every move was refused for an unwritable store."""
    daemon, _ = start(short_dir)
    try:
        assert daemon.status()["moves_refused"] is None
        daemon.loop.policy.store_unwritable = "state store unwritable: database or disk is full"
        assert daemon.status()["moves_refused"] == "state store unwritable: database or disk is full"
    finally:
        daemon.shutdown()


def test_a_dead_simulators_link_is_not_reopened_to_ground_it(short_dir: Path) -> None:
    """Its death is known (the process exited) before the respawn counts it: grounding through
    the lost link had reopened the dead simulator's pty path, by then another program's."""
    daemon, links = start(short_dir)
    try:
        dead = type("Process", (), {"pid": 4321, "returncode": -9})()
        links.simulator = type("Simulator", (), {"alive": lambda _: False, "process": dead})()  # type: ignore[attr-defined]
        grounds = links.amplifiers[0].calls.count("ground")
        assert daemon.link_recovery.ground_lost_link().startswith("not grounded")
        assert links.amplifiers[0].calls.count("ground") == grounds
        links.simulator = None  # type: ignore[attr-defined]
        assert daemon.link_recovery.ground_lost_link() == "output grounded"  # hardware: through the link
    finally:
        daemon.shutdown()
