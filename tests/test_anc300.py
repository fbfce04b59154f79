"""Host driver (feeder.drivers.anc300) against firmware_sim over a pty and TCP."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator

import pytest
import serial
import serial.rfc2217

from feeder.daemon.launcher import Simulator
from feeder.drivers.amplifier import AmplifierError, AmplifierLinkLost, DriveSettings
from feeder.drivers.anc300 import Anc300Amplifier
from feeder.drivers.anc300_link import Anc300Link
from feeder.waveform import Waveform
from firmware_sim.console import ConsoleSession
from firmware_sim.firmware import Firmware
from firmware_sim.transports import PtyConsole

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def sim() -> Iterator[Simulator]:
    simulator = Simulator(["--console", "pty", "--console", "tcp:127.0.0.1:0", "--axes", "2"])
    yield simulator
    simulator.stop()


@pytest.mark.parametrize("endpoint", ["console_pty", "console_tcp"])
def test_driver_configures_steps_waits_and_grounds(sim: Simulator, endpoint: str) -> None:
    with Anc300Amplifier.open(sim.endpoints[endpoint], axis=2, timeout_s=2.0) as amp:
        amp.apply(DriveSettings(frequency_hz=400.0, amplitude_v=35.5, flyback_shape="linear", flyback_s=2e-4))
        amp.enable()
        before = amp.status().step_counter
        start = int(amp.link.value("getcnt 2", "steps"))
        amp.step(-40)
        assert amp.status().moving
        assert amp.wait(5.0)
        status = amp.status()
        assert (status.mode, status.frequency_hz, status.amplitude_v) == ("stp", 400.0, 35.5)
        assert status.step_counter == before - 40 and not status.moving
        assert status.counted_by == "host"
        # the firmware counted what the host counted
        assert int(amp.link.value("getcnt 2", "steps")) - start == -40
        assert amp.link.query("getfb 2")[0] == "flybackshape = custom"  # tables, not setfb
        amp.run_continuous(forward=True)
        assert not amp.wait(0.05)
        amp.ground()
        status = amp.status()
        assert status.mode == "gnd" and not status.moving and status.fault_word == 0
        with pytest.raises(AmplifierError, match="wrong mode"):
            amp.step(3)
        with pytest.raises(AmplifierError):
            amp.step(0)
        with pytest.raises(AmplifierError, match="out of range"):
            amp.apply(DriveSettings(frequency_hz=100.0, amplitude_v=1e4))


def test_driver_uploads_tables_uses_stepw_and_estimates_a_cut_burst(sim: Simulator) -> None:
    link = Anc300Link(sim.endpoints["console_tcp"], timeout_s=2.0)
    amp = Anc300Amplifier(link, axis=1)
    try:
        settings = DriveSettings(
            frequency_hz=200.0, amplitude_v=10.0, flyback_shape="half-cosine", flyback_s=5e-4
        )
        amp.apply(settings)
        up = [int(v) for v in link.query("getpu 1")]
        assert (
            up
            == Waveform(
                frequency_hz=200.0, amplitude_vpp=1.0, flyback_shape="half-cosine", flyback_s=5e-4
            ).anc300_tables()[0]
        )
        start = int(link.value("getcnt 1", "steps"))
        amp.enable()
        amp.step(10)
        assert amp.wait(5.0)
        assert amp.steps_played() == (10, False)  # the driver's own count
        assert int(link.value("getcnt 1", "steps")) - start == 10
        # a burst of 400 steps (2 s) cut after ~0.3 s: the host estimates from time
        amp.step(400)
        time.sleep(0.3)
        amp.stop()
        played, estimated = amp.steps_played()
        true = int(link.value("getcnt 1", "steps")) - start
        assert estimated and amp.status().counted_by == "estimated"
        assert abs(played - true) <= 4, (played, true)  # 4 periods = 20 ms of link latency
        assert not amp.status().moving
    finally:
        amp.ground()
        amp.close()


def test_one_link_shared_by_threads_keeps_replies_apart(sim: Simulator) -> None:
    link = Anc300Link(sim.endpoints["console_pty"], timeout_s=2.0)
    errors: list[str] = []

    def worker(axis: int, volts: float) -> None:
        for _ in range(20):
            link.query(f"setv {axis} {volts}")
            got = float(link.value(f"getv {axis}", "voltage"))
            if got != volts:
                errors.append(f"axis {axis}: {got} != {volts}")

    threads = [threading.Thread(target=worker, args=(1 + k % 2, 10.0 + k)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    link.close()
    assert errors == []


class GarbageSession(ConsoleSession):
    """A console on a noisy line: garbage lines before replies, and once a broken OK."""

    broken_once = True

    def feed(self, data: bytes) -> bytes:
        out = super().feed(data)
        if b"getv" in data and GarbageSession.broken_once:
            GarbageSession.broken_once = False
            return out.replace(b"OK\r\n", b"\x00\xffO#K\r\n")  # never terminated
        return b"\x00\x13 line noise \xfe\r\n" + out if out else out


def test_resync_after_garbage_and_reconnect_after_timeout() -> None:
    fw = Firmware()
    pty = PtyConsole(lambda _source: GarbageSession(fw))
    link = Anc300Link(pty.path, timeout_s=0.5)
    try:
        link.query("setv 1 12.5")  # garbage lines before the reply are skipped
        start = time.monotonic()
        with pytest.raises(AmplifierLinkLost):
            link.query("getv 1")  # the reply never ends: lost within one timeout
        assert time.monotonic() - start < 0.5 + 0.3
        assert link.value("getv 1", "voltage") == "12.500000"  # reconnected, resynchronised
    finally:
        link.close()
        pty.close()


def test_unopenable_device_is_a_lost_link() -> None:
    with pytest.raises(AmplifierLinkLost):
        Anc300Link("/dev/does-not-exist", timeout_s=0.2).query("ver")
    with pytest.raises(AmplifierLinkLost):
        Anc300Link("socket://127.0.0.1:1", timeout_s=0.2).query("ver")


def test_wrong_password_is_refused() -> None:
    fw = Firmware()
    pty = PtyConsole(lambda _source: ConsoleSession(fw, password="secret"))
    try:
        with pytest.raises(AmplifierError, match="password"):
            Anc300Link(pty.path, password="123456", timeout_s=0.5).query("ver")
        link = Anc300Link(pty.path, password="secret", timeout_s=0.5)
        assert link.query("ver")[0].startswith("attocube ANC300")
        link.close()
    finally:
        pty.close()


class Rfc2217Bridge:
    """A minimal RFC 2217 server (pyserial's PortManager) in front of a serial port
    (here firmware_sim's TCP console opened as ``socket://``: a pty refuses the
    modem-line ioctls RFC 2217 forwards)."""

    def __init__(self, device: str) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.device = serial.serial_for_url(device, timeout=0.05)
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        connection, _ = self.listener.accept()
        writer = type("Writer", (), {"write": lambda _self, data: connection.sendall(data)})()
        manager = serial.rfc2217.PortManager(self.device, writer)

        def device_to_network() -> None:
            with contextlib.suppress(OSError, AttributeError, serial.SerialException):
                while self.device.is_open:
                    data = self.device.read(4096)
                    if data:
                        connection.sendall(b"".join(manager.escape(data)))

        threading.Thread(target=device_to_network, daemon=True).start()
        with contextlib.suppress(OSError, AttributeError, serial.SerialException):
            while data := connection.recv(4096):
                self.device.write(b"".join(manager.filter(data)))

    def close(self) -> None:
        self.listener.close()
        self.device.close()


def test_driver_over_rfc2217(sim: Simulator) -> None:
    bridge = Rfc2217Bridge(sim.endpoints["console_tcp"])
    link = Anc300Link(f"rfc2217://127.0.0.1:{bridge.port}", timeout_s=3.0)
    try:
        link.query("setv 1 17.25")
        assert link.value("getv 1", "voltage") == "17.250000"
        assert link.query("ver")[0].startswith("attocube ANC300")
    finally:
        link.close()
        bridge.close()


def test_hold_offset_is_the_offset_mode_and_a_ramp_goes_in_increments(sim: Simulator) -> None:
    """``setm off`` + ``seta``: a real ANC300's offset mode (the voltage alone); step mode and
    ground end it, and the next offset puts the axis back in it."""
    with Anc300Amplifier.open(sim.endpoints["console_tcp"], axis=1, timeout_s=2.0) as amp:
        amp.ground()
        assert amp.ramp_offset(0.0, 1.0, 0.3, 0.0) == 4  # 0.25 V each
        assert amp.status().mode == "off"
        assert float(amp.link.value("geta 1", "voltage")) == 1.0
        amp.enable()
        assert amp.status().mode == "stp"
        amp.hold_offset(0.5)
        assert amp.status().mode == "off"
        amp.ground()  # from the offset (an interrupt): grounded, and the offset set back to 0 V
        assert amp.status().mode == "gnd" and float(amp.link.value("geta 1", "voltage")) == 0.0
        with pytest.raises(AmplifierError, match="increment"):
            amp.ramp_offset(0.0, 1.0, 0.0, 0.0)
