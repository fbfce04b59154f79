"""firmware_sim against hostile or careless hosts: a stepw that would hold the serial console,
numbers a real ANC300 does not take, a CANopen step counter past 2**31, a failing node cycle."""

from __future__ import annotations

import logging
import os
import select
import threading
import time
import tty
from collections.abc import Iterator

import pytest
from test_can_node import Rig, make_rig, wait_emcy

from feeder.protocol.eds import MODES
from firmware_sim.axis import AxisStatus
from firmware_sim.canopen_axis import int32
from firmware_sim.console import ConsoleSession
from firmware_sim.faults import Fault
from firmware_sim.firmware import Firmware
from firmware_sim.transports import PtyConsole

pytestmark = pytest.mark.timeout(60)
WAIT_S = 3.0
"""The sessions' stepw timeout here: a wait that should end at once fails the test well before it."""


def session(fw: Firmware, dialect: str = "anc300") -> ConsoleSession:
    s = ConsoleSession(fw, dialect=dialect, wait_timeout_s=WAIT_S)
    s.feed(b"echo off\r\n")
    return s


def lines(s: ConsoleSession, text: str) -> list[str]:
    """The reply's lines (the real unit's getf line ends with an extra LF: dropped)."""
    return [line.rstrip("\n") for line in s.feed(text.encode() + b"\r\n").decode("ascii").split("\r\n")[:-1]]


# -- stepw ----------------------------------------------------------------------------


class SerialPort:
    """The program's end of the console pty, raw, as a serial port."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.buffer = b""

    def send(self, line: str) -> None:
        os.write(self.fd, line.encode() + b"\r\n")

    def reply(self, timeout_s: float) -> list[str]:
        """The next reply's lines up to its OK/ERROR; what arrived if none within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            got = self.buffer.split(b"\r\n")
            for k, line in enumerate(got[:-1]):
                if line in (b"OK", b"ERROR"):
                    self.buffer = b"\r\n".join(got[k + 1 :])
                    return [x.decode() for x in got[: k + 1]]
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.fd], [], [], left)[0]:
                return [x.decode() for x in got]
            self.buffer += os.read(self.fd, 4096)

    def close(self) -> None:
        os.close(self.fd)


def test_stepw_during_continuous_motion_answers_error_at_once_and_the_serial_console_can_stop(
    ticking: Firmware,
) -> None:
    pty = PtyConsole(lambda _source: session(ticking))
    port = SerialPort(pty.path)
    try:
        for command in ("echo off", "setf 1 100", "setv 1 50", "setm 1 stp", "stepu 1 c"):
            port.send(command)
            assert port.reply(1.0)[-1] == "OK"
        start = time.monotonic()
        port.send("stepw 1")
        port.send("stop 1")
        assert port.reply(1.0) == ["Axis in continuous motion", "ERROR"]
        assert port.reply(1.0) == ["OK"]
        assert time.monotonic() - start < 1.0
        assert not ticking.axis(1).status().moving
    finally:
        port.close()
        pty.close()


@pytest.mark.parametrize(
    ("command", "reply"),
    [
        ("stop 1", ["OK"]),
        ("setm 1 gnd", ["OK"]),
        ("stepd 1 c", ["Axis in continuous motion", "ERROR"]),
    ],
)
def test_a_stepw_on_a_long_burst_ends_when_another_session_stops_grounds_or_runs_on(
    ticking: Firmware, command: str, reply: list[str]
) -> None:
    waiter, other = session(ticking), session(ticking)
    assert lines(waiter, "setf 1 100\r\nsetm 1 stp\r\nstepu 1 100000") == ["OK"] * 3  # 1000 s
    answer: list[str] = []
    thread = threading.Thread(target=lambda: answer.extend(lines(waiter, "stepw 1")))
    thread.start()
    time.sleep(0.2)
    assert thread.is_alive()  # waiting for the burst
    start = time.monotonic()
    assert lines(other, command) == ["OK"]
    thread.join(timeout=WAIT_S + 1)
    assert answer == reply
    assert time.monotonic() - start < 1.0
    assert lines(other, "stop 1\r\nstepw 1") == ["OK", "OK"]  # idle: stepw answers at once


def test_capw_during_continuous_motion_answers_error_at_once(ticking: Firmware) -> None:
    s = session(ticking)
    start = time.monotonic()
    assert lines(s, "setm 1 stp\r\nstepd 1 0\r\ncapw 1") == ["OK", "OK", "Axis in continuous motion", "ERROR"]
    assert time.monotonic() - start < 1.0


# -- numbers --------------------------------------------------------------------------


@pytest.mark.parametrize("dialect", ["anc300", "extended"])
@pytest.mark.parametrize(
    "command",
    [
        "setv 1 1_50",
        "setv 1 \uff11\uff12\uff10",  # fullwidth 120
        "setv 1 \u0661\u0665\u0660",  # Arabic-Indic 150
        "setv 1 \u0967\u0968",  # Devanagari 12
        "setf 1 2_000",
        "seta 1 1_0",
        "setv 1 0x10",
        "setv 1 inf",
        "setv 1 nan",
        "setv 1 1e",
        "setv 1 --1",
        "setv 1 1.2.3",
        "setv 1 .",
        "setv 1 1e1_0",
        "setv 1 1e400",
    ],
)
def test_only_ascii_decimal_numbers_are_taken(dialect: str, command: str) -> None:
    s = session(Firmware(), dialect)
    assert lines(s, "setv 1 10\r\nsetf 1 200\r\nseta 1 5") == ["OK"] * 3
    name = {"setv": "voltage", "setf": "frequency", "seta": "offset"}[command[:4]]
    assert lines(s, command) == [f"Invalid number for {name}", "ERROR"]
    assert lines(s, "getv 1\r\ngetf 1\r\ngeta 1") == [
        "voltage = 10.000000 V",
        "OK",
        "frequency = 200 Hz",
        "OK",
        "voltage = 5.000000 V",
        "OK",
    ]


@pytest.mark.parametrize("dialect", ["anc300", "extended"])
@pytest.mark.parametrize(
    ("text", "volts"),
    [("1e2", 100.0), ("+12", 12.0), (".5", 0.5), ("7.", 7.0), ("2.5E+1", 25.0), ("-0.0e3", 0.0)],
)
def test_plain_numbers_and_exponents_are_taken(dialect: str, text: str, volts: float) -> None:
    s = session(Firmware(), dialect)
    assert lines(s, f"setv 1 {text}\r\ngetv 1") == ["OK", f"voltage = {volts:.6f} V", "OK"]


@pytest.mark.parametrize("dialect", ["anc300", "extended"])
def test_minus_zero_reads_back_as_zero(dialect: str) -> None:
    s = session(Firmware(), dialect)
    assert lines(s, "setv 1 -0\r\nseta 1 -0.0\r\ngetv 1\r\ngeta 1") == [
        "OK",
        "OK",
        "voltage = 0.000000 V",
        "OK",
        "voltage = 0.000000 V",
        "OK",
    ]


# -- CANopen ----------------------------------------------------------------------------


@pytest.fixture
def rig() -> Iterator[Rig]:
    yield from make_rig()


def burst_by_rpdo(rig: Rig, steps: int, sequence: int) -> None:
    rpdo = rig.master.rpdo[1]
    rpdo["Step command"].raw = steps
    rpdo["Command sequence"].raw = sequence
    rpdo.transmit()
    rig.tpdo_until(lambda p: p["Command acknowledge"].raw == sequence)


@pytest.mark.parametrize(("start", "steps"), [(2**31 - 5, 20), (-(2**31) + 3, -10)])
def test_step_counter_wraps_as_int32_and_the_node_keeps_running(rig: Rig, start: int, steps: int) -> None:
    sdo = rig.master.sdo
    sdo["Amplitude"].raw = 50_000
    sdo["Frequency"].raw = 2_000_000
    sdo["Mode"].raw = MODES.index("stp")
    rig.master.nmt.state = "OPERATIONAL"
    with rig.firmware.lock:
        rig.firmware.axis(1)._step_counter = start  # days of stepping one way, skipped
    burst_by_rpdo(rig, steps, 1)
    rig.run(0.05)
    assert not rig.firmware.axis(1).status().moving
    wrapped = int32(start + steps)
    assert wrapped == start + steps - (2**32 if steps > 0 else -(2**32))
    rig.tpdo_until(lambda p: p["Step counter"].raw == wrapped)
    assert sdo["Step counter"].raw == wrapped
    assert int32(wrapped - int32(start)) == steps  # a host's difference modulo 2**32
    burst_by_rpdo(rig, 0, 2)  # the node still acknowledges commands ...
    rig.firmware.axis(1).inject_fault(Fault.OVERTEMP)
    wait_emcy(rig.master, 0x4200)  # ... and reports faults
    assert rig.node._thread.is_alive()


def test_a_failing_node_cycle_is_logged_grounds_the_axis_and_the_node_goes_on(
    rig: Rig, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    sdo = rig.master.sdo
    sdo["Mode"].raw = MODES.index("stp")
    rig.master.nmt.state = "OPERATIONAL"
    burst_by_rpdo(rig, 1_000_000, 1)
    port = rig.node.ports[0]
    pack = port.pack_tpdo
    failed = threading.Event()

    def pack_once_failing(status: AxisStatus, register: int) -> bytes:
        if not failed.is_set():
            failed.set()
            raise RuntimeError("injected")
        return pack(status, register)

    with caplog.at_level(logging.ERROR, logger="firmware_sim.canopen_node"):
        monkeypatch.setattr(port, "pack_tpdo", pack_once_failing)
        rig.node._wake.set()
        assert failed.wait(2.0)
        rig.tpdo_until(lambda p: p["Status word"].raw == 0)  # grounded: not moving, not in a stepping mode
    assert rig.firmware.axis(1).status().mode == "gnd"
    [record] = [r for r in caplog.records if r.name == "firmware_sim.canopen_node"]
    assert record.levelno == logging.ERROR and record.exc_info is not None
    assert rig.node._thread.is_alive()
    sdo["Mode"].raw = MODES.index("stp")  # the host selects a stepping mode again
    burst_by_rpdo(rig, 5, 2)
    rig.run(0.1)
    rig.tpdo_until(lambda p: p["Step counter"].raw == 5)
