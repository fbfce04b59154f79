"""The ANC300 driver against what a real unit does: whole hertz, 38400 baud, a slow TCP greeting."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import serial
from listener import Listener
from serial.urlhandler.protocol_socket import Serial as SocketSerial

import feeder.drivers.anc300 as anc300
import feeder.drivers.anc300_link as anc300_link
from feeder.drivers.amplifier import AmplifierError, AmplifierLinkLost, DriveSettings
from feeder.drivers.anc300 import Anc300Amplifier
from feeder.drivers.anc300_link import Anc300Link
from feeder.protocol.anc300 import MOVE_PATH
from firmware_sim.console import ConsoleSession
from firmware_sim.firmware import Firmware
from firmware_sim.transports import PtyConsole

pytestmark = pytest.mark.timeout(60)


class RecordingSession(ConsoleSession):
    """An ANC300-dialect console that keeps every command line it was sent."""

    def __init__(self, firmware: Firmware, lines: list[str], **options: Any) -> None:
        super().__init__(firmware, dialect="anc300", **options)
        self.lines = lines
        self._partial = b""

    def feed(self, data: bytes) -> bytes:
        *complete, self._partial = (self._partial + data).split(b"\n")
        self.lines += [line.decode().strip() for line in complete]
        return super().feed(data)


class SilentSession(ConsoleSession):
    """A serial console that sends nothing when the port opens (the ANC300's USB port)."""

    def greeting(self) -> bytes:
        return b""


@pytest.fixture
def recorded() -> Iterator[tuple[Anc300Link, list[str]]]:
    lines: list[str] = []
    pty = PtyConsole(lambda _source: RecordingSession(Firmware(), lines))
    link = Anc300Link(pty.path, timeout_s=1.0)
    yield link, lines
    link.close()
    pty.close()


def test_the_frequency_goes_out_in_whole_hertz_and_the_units_answer_times_the_burst(
    recorded: tuple[Anc300Link, list[str]],
) -> None:
    link, lines = recorded
    now = [0.0]
    amp = Anc300Amplifier(link, axis=1, clock=lambda: now[0])
    amp.apply(DriveSettings(frequency_hz=1070.290630, amplitude_v=20.0))
    assert "setf 1 1070" in lines
    assert not any(line.startswith("setf") and "." in line for line in lines)
    assert amp.status().frequency_hz == 1070.0
    # 2.4 Hz asked, 2 Hz played: the host's estimate of a burst runs at the unit's 2 Hz
    amp.apply(DriveSettings(frequency_hz=2.4, amplitude_v=20.0))
    assert "setf 1 2" in lines and lines[lines.index("setf 1 2") + 1] == "getf 1"
    amp.enable()
    amp.step(10)
    now[0] = 2.5
    assert amp.steps_played() == (5, True)  # 2.5 s × 2 Hz (2.4 Hz would say 6)
    now[0] = 4.5
    assert amp.steps_played() == (9, True)  # still running: over at 10/2 s, not 10/2.4 s
    now[0] = 5.0 + anc300.BURST_END_MARGIN_S
    assert amp.steps_played() == (10, False)
    amp.ground()


def test_the_strict_console_runs_whole_hertz_and_the_extended_one_fractions() -> None:
    fw = Firmware()
    strict = ConsoleSession(fw, dialect="anc300")
    strict.feed(b"echo off\r\n")
    # the unit's getf line ends in an extra LF (the driver reads the frequency all the same: above)
    assert strict.feed(b"setf 1 1070.6\r\ngetf 1\r\n") == b"OK\r\nfrequency = 1071 Hz\n\r\nOK\r\n"
    assert strict.feed(b"setf 1 0.4\r\n").endswith(b"ERROR\r\n")  # 0 Hz: out of range
    extended = ConsoleSession(fw, dialect="extended")
    extended.feed(b"echo off\r\n")
    assert extended.feed(b"setf 1 1070.5\r\ngetf 1\r\n") == b"OK\r\nfrequency = 1070.500000 Hz\r\nOK\r\n"


def test_serial_ports_open_at_the_anc300s_38400_baud_or_the_given_rate(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    opened: list[dict[str, Any]] = []

    def refuse(url: str, **options: Any) -> serial.SerialBase:
        opened.append(options)
        raise serial.SerialException(f"{url}: no such port")

    monkeypatch.setattr(anc300_link.serial, "serial_for_url", refuse)
    with pytest.raises(AmplifierLinkLost, match="cannot open"):
        Anc300Link("/dev/ttyUSB7").query("ver")
    with pytest.raises(AmplifierLinkLost, match="cannot open"):
        Anc300Amplifier.open("/dev/ttyUSB7", axis=2, timeout_s=0.5, baudrate=9600).status()
    assert [o["baudrate"] for o in opened] == [38400, 9600]
    assert opened[1]["timeout"] == 0.5


class SlowGreetingServer:
    """A TCP console (firmware_sim's session, password ``secret``) that greets each
    connection only after ``delay_s`` (None: never)."""

    def __init__(self, delay_s: float | None) -> None:
        self.delay_s = delay_s
        self.sessions: list[ConsoleSession] = []
        self._listener = Listener(socket.create_server(("127.0.0.1", 0)), self._accepted)
        self.url = f"socket://127.0.0.1:{self._listener.port}"

    def _accepted(self, conn: socket.socket) -> None:
        threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        session = ConsoleSession(Firmware(), password="secret", dialect="anc300")
        self.sessions.append(session)
        with conn, contextlib.suppress(OSError):
            if self.delay_s is None:
                while conn.recv(4096):
                    pass
                return
            time.sleep(self.delay_s)
            conn.sendall(session.greeting())
            while (data := conn.recv(4096)) and not session.closed:
                conn.sendall(session.feed(data))

    def close(self) -> None:
        self._listener.close()


def test_a_tcp_console_that_greets_late_is_logged_in_without_a_failed_try() -> None:
    server = SlowGreetingServer(delay_s=0.4)
    link = Anc300Link(server.url, password="secret", timeout_s=1.0)
    try:
        assert link.query("ver")[0].startswith("attocube ANC300")
        session = server.sessions[0]
        assert session.logged_in and session.failed_logins == 0  # "echo off" was no password
    finally:
        link.close()
        server.close()


def test_a_greeting_that_arrived_before_the_driver_looked_is_not_flushed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    server = SlowGreetingServer(delay_s=0.0)
    configure = SocketSerial._reconfigure_port

    def slow_host(port: SocketSerial) -> None:
        if not port.is_open:  # opening, on a loaded host: the greeting is in before the flush
            time.sleep(0.3)
        configure(port)

    monkeypatch.setattr(SocketSerial, "_reconfigure_port", slow_host)
    link = Anc300Link(server.url, password="secret", timeout_s=1.0)
    try:
        assert link.query("ver")[0].startswith("attocube ANC300")
        assert server.sessions[0].failed_logins == 0
    finally:
        link.close()
        server.close()


def test_a_tcp_console_that_never_greets_is_a_lost_link_in_one_line() -> None:
    server = SlowGreetingServer(delay_s=None)
    try:
        start = time.monotonic()
        with pytest.raises(AmplifierLinkLost, match=r"no greeting within 0\.3 s") as err:
            Anc300Link(server.url, password="secret", timeout_s=0.3).query("ver")
        assert time.monotonic() - start < 0.3 + 0.5
        assert "\n" not in str(err.value)
    finally:
        server.close()


class LateGreetingSession(ConsoleSession):
    """A serial console behind a slow line: its greeting and password prompt come 0.3 s late."""

    def greeting(self) -> bytes:
        time.sleep(0.3)
        return super().greeting()


def test_a_serial_console_that_asks_for_the_password_late_is_logged_in() -> None:
    sessions: list[ConsoleSession] = []

    def late(_source: str) -> ConsoleSession:
        sessions.append(LateGreetingSession(Firmware(), password="secret"))
        return sessions[-1]

    pty = PtyConsole(late)
    link = Anc300Link(pty.path, password="secret", timeout_s=1.0)
    try:
        # "echo off" went out before the prompt came and was taken as a password: the driver
        # logs in then (one failed try), not "wrong password" (the prompt and the masked
        # "echo off" share a line)
        assert link.query("ver")[0].startswith("attocube ANC300")
        assert sessions[0].logged_in and sessions[0].failed_logins == 1
    finally:
        link.close()
        pty.close()


def test_a_serial_console_that_sends_no_greeting_is_used_at_once() -> None:
    fw = Firmware()
    pty = PtyConsole(lambda _source: SilentSession(fw))
    link = Anc300Link(pty.path, timeout_s=2.0)
    try:
        start = time.monotonic()
        link.query("setv 1 12.5")
        assert time.monotonic() - start < 1.0  # no wait for a greeting that never comes
        assert link.value("getv 1", "voltage") == "12.500000"
    finally:
        link.close()
        pty.close()


class StepwSession(ConsoleSession):
    """A console that never answers ``stepw``: the burst plays on (``on_stepw`` runs instead)."""

    def __init__(self, firmware: Firmware, on_stepw: Any) -> None:
        super().__init__(firmware, dialect="anc300")
        self.on_stepw = on_stepw

    def feed(self, data: bytes) -> bytes:
        if b"stepw" in data:
            self.on_stepw()
            return b""
        return super().feed(data)


@pytest.mark.parametrize("breaks", [False, True], ids=["slow burst", "link breaks"])
def test_stepw_without_an_answer_is_a_slow_burst_but_a_broken_link_is_lost(breaks: bool) -> None:
    """A link closed during ``stepw`` was reported as 'the burst did not finish in time' (no fault,
    no ground, no reconnect); now only a reply that does not come in time is that."""
    ptys: list[PtyConsole] = []

    def on_stepw() -> None:
        if breaks:
            threading.Timer(0.1, ptys[0].close).start()

    ptys.append(PtyConsole(lambda _source: StepwSession(Firmware(), on_stepw)))
    amp = Anc300Amplifier(Anc300Link(ptys[0].path, timeout_s=1.0), axis=1)
    try:
        amp.enable()
        amp.apply(DriveSettings(1000.0, 30.0))
        amp.step(5)
        if breaks:
            with pytest.raises(AmplifierLinkLost) as err:
                amp.wait(1.0)
            assert not isinstance(err.value, anc300_link.ReplyTimeout)
        else:
            assert amp.wait(0.5) is False
    finally:
        amp.link.close()
        if not breaks:
            ptys[0].close()


def test_every_verb_the_driver_sends_is_on_the_move_path(recorded: tuple[Anc300Link, list[str]]) -> None:
    """What the daemon may send a real unit (MOVE_PATH, all real verbs): every driver call,
    the camera calibration's offsets included (``seta`` was missing)."""
    link, lines = recorded
    amp = Anc300Amplifier(link, axis=1)
    amp.apply(DriveSettings(frequency_hz=1000.0, amplitude_v=20.0))
    amp.enable()
    amp.step(3)  # the firmware does not tick here: the burst plays until stopped (stepw: below)
    amp.stop()
    amp.run_continuous(forward=False)
    amp.stop()
    assert amp.wait(1.0)
    amp.status()
    amp.steps_played()
    amp.hold_offset(5.0)
    amp.hold_offset(6.0)
    amp.ground()
    sent = {line.split()[0] for line in lines if line}
    assert {"setf", "getf", "setv", "stepu", "stepd", "stepw", "stop", "seta", "setm", "getm"} <= sent
    assert sent <= MOVE_PATH


class NoOffsetSession(RecordingSession):
    """A unit whose axis 1 has no offset mode (as an ANM150 module): ``setm 1 off`` is refused."""

    def feed(self, data: bytes) -> bytes:
        if b"setm 1 off" in data:
            return b"Error: mode not available on this module\r\nERROR\r\n"
        return super().feed(data)


def test_a_module_without_offset_mode_is_named_with_the_way_around_it() -> None:
    pty = PtyConsole(lambda _source: NoOffsetSession(Firmware(), []))
    link = Anc300Link(pty.path, timeout_s=1.0)
    try:
        amp = Anc300Amplifier(link, axis=1)
        with pytest.raises(AmplifierError) as err:
            amp.hold_offset(10.0)
        assert not isinstance(err.value, AmplifierLinkLost)  # the link stays: nothing reconnects
        message = str(err.value)
        assert "mode not available on this module" in message and "holds no offset" in message
        assert "--x-move" in message and "[camera] aligned" in message and "\n" not in message
        amp.ground()  # the link still answers
    finally:
        link.close()
        pty.close()


def test_a_closed_link_refuses_commands_and_never_reopens_its_port(
    recorded: tuple[Anc300Link, list[str]],
) -> None:
    """A command through a closed link reopened the port by its path: a dead simulator's pty may
    be another program's by then, and the reopened serial port (held exclusively) refused the
    daemon's reconnect for good."""
    link, lines = recorded
    amp = Anc300Amplifier(link, axis=1)
    amp.ground()
    sent = len(lines)
    amp.close()
    with pytest.raises(AmplifierLinkLost, match="the link is closed"):
        amp.ground()
    assert link._port is None and len(lines) == sent
    again = Anc300Link(link.url, timeout_s=1.0)  # the reconnect's new link opens the port
    try:
        assert again.value("getm 1", "mode") == "gnd"
    finally:
        again.close()
