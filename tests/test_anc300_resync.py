"""The ANC300 link recovers without relying on the unit dropping anything.

A real ANC300's serial console does not reset on DTR: a reply that comes after the driver
gave up on it stays in the stream, as do the session and its settings.  firmware_sim's pty
does the same (``PtyConsole(keep_session=True)``, the default), so these tests show that the
driver resynchronises on the ``ver`` reply (and stops the axes) instead of taking a late
``OK`` for the next command's, checks the unit's identity and holds the port exclusively.
"""

from __future__ import annotations

import os
import select
import time
from collections.abc import Iterator
from typing import Any

import pytest
import serial

from feeder.drivers.amplifier import AmplifierError, AmplifierLinkLost, DriveSettings
from feeder.drivers.anc300 import Anc300Amplifier
from feeder.drivers.anc300_link import Anc300Link, ReplyTimeout
from firmware_sim.console import ConsoleSession
from firmware_sim.firmware import Firmware
from firmware_sim.transports import PtyConsole

pytestmark = pytest.mark.timeout(30)


class SlowSession(ConsoleSession):
    """An ANC300-dialect console on a busy unit: every reply takes ``every_s``, and the
    ``n``-th line starting with one of ``slow`` (counted across them) takes ``late_s`` more.
    Keeps every command line it was sent in ``lines``."""

    def __init__(
        self,
        firmware: Firmware,
        lines: list[str],
        slow: dict[str, int] | None = None,
        late_s: float = 0.0,
        every_s: float = 0.0,
        **options: Any,
    ) -> None:
        super().__init__(firmware, dialect="anc300", **options)
        self.lines = lines
        self.slow = dict(slow or {})
        self.late_s = late_s
        self.every_s = every_s

    def feed(self, data: bytes) -> bytes:
        sent = [line.strip() for line in data.decode(errors="replace").splitlines() if line.strip()]
        self.lines += sent
        out = super().feed(data)
        for line in sent:
            for prefix in self.slow:
                if line.startswith(prefix):
                    self.slow[prefix] -= 1
                    if self.slow[prefix] == 0:
                        time.sleep(self.late_s)
        if sent:
            time.sleep(self.every_s)
        return out


def console(
    firmware: Firmware | None = None, keep_session: bool = True, **options: Any
) -> tuple[PtyConsole, list[str]]:
    lines: list[str] = []
    fw = firmware or Firmware()
    return PtyConsole(lambda _source: SlowSession(fw, lines, **options), keep_session=keep_session), lines


@pytest.fixture
def closing() -> Iterator[list[Any]]:
    """Things with a close() method, closed after the test (last first)."""
    things: list[Any] = []
    yield things
    for thing in reversed(things):
        thing.close()


# -- the driver --------------------------------------------------------------------------


def test_a_late_reply_is_not_taken_for_the_next_commands_answer(closing: list[Any]) -> None:
    """``getm 1`` answers 0.5 s late (the link waits 0.3 s), every reply 50 ms: the old driver
    reconnected, took that late reply for ``echo off``'s and was one reply behind from then on
    (``getv`` got ``setv``'s bare OK: 'no voltage line'); now every command gets its own."""
    pty, _ = console(slow={"getm 1": 1}, late_s=0.5, every_s=0.05)
    link = Anc300Link(pty.path, timeout_s=0.3)
    closing += [pty, link]
    link.query("setv 1 12.5")
    with pytest.raises(ReplyTimeout):
        link.query("getm 1")
    link.query("setv 1 20")
    assert link.value("getv 1", "voltage") == "20.000000"
    link.query("setf 1 250")
    assert link.value("getf 1", "frequency") == "250"
    assert link.value("getm 1", "mode") == "gnd"
    assert link.value("getv 1", "voltage") == "20.000000"


def test_a_ver_reply_left_over_from_an_earlier_resync_is_skipped(closing: list[Any]) -> None:
    """``getm 1`` times out, then the resynchronising ``ver`` does too (its reply comes 0.5 s
    late; every reply takes 50 ms): the next resynchronisation sees that stale ``ver`` reply
    first, and its own one before ``echo off``'s OK; it is skipped, not taken for ``echo off``'s
    (which would leave ``echo off``'s OK to answer ``setv``, and ``setv``'s to answer ``getv``)."""
    pty, lines = console(slow={"getm 1": 1, "ver": 2}, late_s=0.5, every_s=0.05)
    link = Anc300Link(pty.path, timeout_s=0.3)
    closing += [pty, link]
    link.query("setv 1 7")
    with pytest.raises(ReplyTimeout):
        link.query("getm 1")
    with pytest.raises(ReplyTimeout, match="ver"):
        link.query("setv 1 20")  # resynchronising: ver answered too late
    link.query("setv 1 21")
    assert link.value("getv 1", "voltage") == "21.000000"
    assert link.value("getm 1", "mode") == "gnd"
    assert lines.count("ver") == 3


def test_a_stepw_that_runs_over_stops_the_axes_first_after_resynchronising(closing: list[Any]) -> None:
    """The burst never ends (the firmware does not tick): ``stepw`` times out on the link and the
    console answers it with ERROR later.  The next command drains that, resynchronises and sends
    ``stop`` to the link's axes before itself; the host's count of the burst is then estimated."""
    fw = Firmware()
    pty, lines = console(fw, wait_timeout_s=0.3)
    link = Anc300Link(pty.path, timeout_s=0.5)
    now = [0.0]
    amp = Anc300Amplifier(link, axis=1, clock=lambda: now[0])
    closing += [pty, link]
    amp.apply(DriveSettings(frequency_hz=100.0, amplitude_v=20.0))
    amp.enable()
    amp.step(50)  # 0.5 s by the host's clock
    now[0] = 0.45
    assert amp.wait(0.1) is False  # stepw not answered in time
    assert fw.axis(1).status().moving
    status = amp.status()
    tail = lines[lines.index("stepw 1") + 1 :]
    assert tail[:3] == ["ver", "echo off", "stop 1"], tail
    assert tail[3:] == ["getm 1", "getf 1", "getv 1"]
    assert not fw.axis(1).status().moving
    assert status.mode == "stp" and not status.moving and status.counted_by == "estimated"
    assert amp.steps_played() == (45, True)  # cut where the host's clock was at the stop


def test_a_device_that_is_no_anc300_is_refused_naming_the_port_and_its_answer(closing: list[Any]) -> None:
    class Multimeter(ConsoleSession):
        def feed(self, data: bytes) -> bytes:
            return b"KEITHLEY INSTRUMENTS,MODEL 2000\r\nOK\r\n" if b"\n" in data else b""

    pty = PtyConsole(lambda _source: Multimeter(Firmware()))
    closing.append(pty)
    with pytest.raises(AmplifierError, match="not an attocube ANC300") as err:
        Anc300Link(pty.path, timeout_s=0.3).query("getv 1")
    assert not isinstance(err.value, AmplifierLinkLost)
    assert pty.path in str(err.value) and "MODEL 2000" in str(err.value)
    port = serial.Serial(pty.path, exclusive=True)  # the refused link let go of the port
    port.close()


def test_the_identity_is_read_at_connect_from_a_two_line_ver_reply(closing: list[Any]) -> None:
    pty, lines = console()
    link = Anc300Link(pty.path, timeout_s=1.0)
    closing += [pty, link]
    link.query("getv 1")
    assert lines[:2] == ["ver", "echo off"]
    assert link.version[0].startswith("attocube ANC300 controller version")
    assert link.version[1] == "ANC150 compatibillity console"


def test_a_serial_port_is_held_exclusively(closing: list[Any]) -> None:
    pty, _ = console()
    first = Anc300Link(pty.path, timeout_s=0.5)
    closing += [pty, first]
    first.query("getv 1")
    second = Anc300Link(pty.path, timeout_s=0.5)
    with pytest.raises(AmplifierLinkLost, match="in use by another program") as err:
        second.query("getv 1")
    assert pty.path in str(err.value)
    first.close()
    assert second.value("getv 1", "voltage") == "0.000000"
    second.close()


def test_connecting_costs_one_round_trip_more_than_before(closing: list[Any]) -> None:
    """Connect = the serial greeting's 0.1 s of quiet + ``ver`` + ``echo off`` (+ the command):
    about 102 ms on a pty, 1 ms more than before; the bound leaves room for a loaded machine."""
    pty, _ = console()
    closing.append(pty)
    start = time.monotonic()
    link = Anc300Link(pty.path, timeout_s=1.0)
    link.query("getv 1")
    link.close()
    assert time.monotonic() - start < 0.6


# -- the simulator's pty -------------------------------------------------------------------


class RawPort:
    """The pty opened as a program would, read with a deadline."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)

    def send(self, line: str) -> None:
        os.write(self.fd, line.encode() + b"\r\n")

    def read(self, wait_s: float) -> bytes:
        got = b""
        deadline = time.monotonic() + wait_s
        while (left := deadline - time.monotonic()) > 0 and select.select([self.fd], [], [], left)[0]:
            got += os.read(self.fd, 4096)
        return got

    def close(self) -> None:
        os.close(self.fd)


@pytest.mark.parametrize("keep_session", [True, False], ids=["real unit", "resets on DTR"])
def test_the_pty_keeps_the_session_and_unread_replies_when_closed_like_a_real_unit(
    keep_session: bool, closing: list[Any]
) -> None:
    pty, _ = console(keep_session=keep_session, slow={"getf 1": 1}, late_s=0.3)
    closing.append(pty)
    port = RawPort(pty.path)
    port.send("echo off")
    assert port.read(0.2).endswith(b"OK\r\n")
    port.send("getv 1")  # answered, never read
    time.sleep(0.1)
    port.close()
    time.sleep(0.05)  # the console sees the hang-up
    port = RawPort(pty.path)
    assert port.read(0.2) == (b"voltage = 0.000000 V\r\nOK\r\n" if keep_session else b"")
    port.send("getf 1")  # answered 0.3 s late, after the program closed the pty
    port.close()
    time.sleep(0.4)
    port = RawPort(pty.path)
    late = port.read(0.2)
    assert late == (b"frequency = 100 Hz\n\r\nOK\r\n" if keep_session else b"")  # the unit's getf LF
    port.send("getm 1")  # a new session echoes and prompts; the kept one had echo off
    reply = port.read(0.3)
    port.close()
    assert reply == (b"mode = gnd\r\nOK\r\n" if keep_session else b"getm 1\r\nmode = gnd\r\nOK\r\n> ")
