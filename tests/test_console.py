"""ANC300 console: framing, getters, login, echo, errors, TCP server, property-based fuzz."""

from __future__ import annotations

import contextlib
import re
import socket
import time
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from feeder.plant.stack import StackParameters
from firmware_sim.clock import VirtualClock
from firmware_sim.console import AXIS_VERBS, ConsoleSession
from firmware_sim.firmware import Firmware, FirmwareConfig
from firmware_sim.transports import MAX_CONSOLE_CLIENTS, MAX_PENDING_LOGINS, TcpConsoleServer

TERMINATOR = re.compile(r"^(OK|ERROR)$")


def reply_lines(session: ConsoleSession, text: str) -> list[str]:
    out = session.feed(text.encode()).decode("ascii")
    assert out.endswith("\r\n")
    assert "\n" not in out.replace("\r\n", "")  # CRLF on every line
    return out.split("\r\n")[:-1]


@pytest.fixture
def session() -> ConsoleSession:
    s = ConsoleSession(Firmware(), wait_timeout_s=0.5)
    s.feed(b"echo off\r\n")
    return s


def test_getters_answer_name_value_unit_in_plain_fixed_point(session: ConsoleSession) -> None:
    assert reply_lines(session, "setv 1 30.5\r\n") == ["OK"]
    assert reply_lines(session, "getv 1\r\n") == ["voltage = 30.500000 V", "OK"]
    assert reply_lines(session, "getf 1\r\n") == ["frequency = 100 Hz", "OK"]
    assert reply_lines(session, "getm 1\r\n") == ["mode = gnd", "OK"]
    nominal_nf = StackParameters().capacitance_f * 1e9
    assert reply_lines(session, "getc 1\r\n") == [f"capacitance = {nominal_nf:.6f} nF", "OK"]
    assert reply_lines(session, "seta 1 0.000001\r\n") == ["OK"]
    assert reply_lines(session, "geta 1\r\n") == ["voltage = 0.000001 V", "OK"]
    assert reply_lines(session, "ver\r\n")[0].startswith("attocube ANC300")


def test_errors_are_message_then_error_and_empty_slots_refuse(session: ConsoleSession) -> None:
    assert reply_lines(session, "stepu 1 5\r\n") == ["Axis in wrong mode", "ERROR"]
    assert reply_lines(session, "getf 4\r\n") == ["No axis in slot 4", "ERROR"]
    assert reply_lines(session, "getf 9\r\n")[-1] == "ERROR"
    assert reply_lines(session, "setv 1 1e300\r\n")[-1] == "ERROR"
    assert reply_lines(session, "setf 1 abc\r\n") == ["Invalid number for frequency", "ERROR"]
    assert reply_lines(session, "bogus OK ERROR\r\n") == ["Unknown command", "ERROR"]
    lines = reply_lines(session, "setv 1 999\r\n")
    assert lines[-1] == "ERROR" and "e+" not in lines[0] and "999" in lines[0]


def test_pattern_tables_round_trip(session: ConsoleSession) -> None:
    table = [(7 * i) % 256 for i in range(256)]
    assert reply_lines(session, "setpu 1 " + " ".join(map(str, table)) + "\r\n") == ["OK"]
    assert reply_lines(session, "getpu 1\r\n") == [*map(str, table), "OK"]
    assert reply_lines(session, "setpd 1 1 2 3\r\n") == ["Wrong number of arguments", "ERROR"]
    bad = " ".join(["300"] * 256)
    assert reply_lines(session, f"setpd 1 {bad}\r\n")[-1] == "ERROR"


def test_echo_and_prompt() -> None:
    s = ConsoleSession(Firmware())
    assert s.feed(b"getm 2\r\n") == b"getm 2\r\nmode = gnd\r\nOK\r\n> "
    assert s.feed(b"echo off\r\n") == b"echo off\r\nOK\r\n"
    assert s.feed(b"getm 2\n") == b"mode = gnd\r\nOK\r\n"  # LF alone ends a line too


def test_login_buffers_typed_ahead_input_and_closes_after_three_failures() -> None:
    s = ConsoleSession(Firmware(), password="123456")
    assert s.greeting().endswith(b"Authorization code: ")
    out = s.feed(b"123456\r\necho off\r\ngetf 1\r\n")
    assert out == (b"******\r\nAuthorization success\r\necho off\r\nOK\r\nfrequency = 100 Hz\r\nOK\r\n")
    s = ConsoleSession(Firmware(), password="123456")
    for _ in range(2):
        assert s.feed(b"wrong\r\n").endswith(b"Authorization failed\r\nAuthorization code: ")
    s.feed(b"getf 1\r\n")
    assert s.closed


def test_long_line_and_non_utf8_get_errors_and_the_console_keeps_working(session: ConsoleSession) -> None:
    out = session.feed(b"x" * 65536)
    assert out == b"Line too long\r\nERROR\r\n"
    assert session.feed(b"yyy\r\n") == b""  # the rest of the long line is dropped
    assert reply_lines(session, "\xff\xfe\r\n") == ["Unknown command", "ERROR"]
    assert session.feed(b"\xff\xfe\x00\r\ngetm 1\r\n").endswith(b"mode = gnd\r\nOK\r\n")


def test_stepw_waits_for_the_burst_and_counter_extension(ticking: Firmware) -> None:
    s = ConsoleSession(ticking)
    s.feed(b"echo off\r\n")
    assert reply_lines(s, "setf 1 500\r\nsetv 1 20\r\nsetm 1 stp\r\n") == ["OK"] * 3
    start = time.monotonic()  # before stepu: the burst starts with it
    assert reply_lines(s, "stepu 1 25\r\nstepw 1\r\n") == ["OK", "OK"]
    assert time.monotonic() - start >= 0.04  # 25 periods of 2 ms
    assert reply_lines(s, "getcnt 1\r\n") == ["steps = 25", "OK"]
    assert reply_lines(s, "stepd 1 0\r\n") == ["OK"]  # 0 = continuous, as on real units
    assert "moving = 1" in reply_lines(s, "getst 1\r\n")
    assert reply_lines(s, "stop 1\r\ngetst 1\r\n")[-2:] == ["faultnames = none", "OK"]
    assert reply_lines(s, "injf 1 overtemp\r\ngetm 1\r\n") == ["OK", "mode = gnd", "OK"]
    assert reply_lines(s, "setm 1 stp\r\n") == ["Axis in fault state", "ERROR"]
    assert reply_lines(s, "clrf 1\r\nsetm 1 stp\r\n") == ["OK", "OK"]


# -- TCP ----------------------------------------------------------------------


def _connect(port: int) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    return sock


def _read_until(sock: socket.socket, marker: bytes) -> bytes:
    data = b""
    while marker not in data:
        chunk = sock.recv(4096)
        if not chunk:
            break
        data += chunk
    return data


@pytest.mark.timeout(60)
def test_tcp_server_survives_abuse_and_many_clients() -> None:
    fw = Firmware()
    server = TcpConsoleServer("127.0.0.1", 0, lambda _source: ConsoleSession(fw, password="123456"))
    try:
        # disconnect mid-line, 64 KiB without newline, non-UTF-8, login never finished
        for payload in (b"getf 1", b"z" * 65536, b"\xff\xfe\xfd\r\n", b""):
            sock = _connect(server.port)
            sock.sendall(payload)
            sock.close()
        socks = [_connect(server.port) for _ in range(MAX_CONSOLE_CLIENTS + 8)]
        # idle at the prompt: each new one evicts the longest-waiting, the newest are greeted
        assert all(
            b"Authorization code" in _read_until(sock, b"code: ") for sock in socks[-MAX_PENDING_LOGINS:]
        )
        sock = _connect(server.port)
        _read_until(sock, b"code: ")
        sock.sendall(b"123456\r\necho off\r\ngetv 2\r\n")
        assert b"voltage = 0.000000 V\r\nOK\r\n" in _read_until(sock, b"V\r\nOK\r\n")
        sock.close()
        for sock in socks:
            sock.close()
    finally:
        server.close()


def test_tcp_server_refuses_other_addresses() -> None:
    with pytest.raises(ValueError):
        TcpConsoleServer("0.0.0.0", 0, lambda _source: ConsoleSession(Firmware()))


# -- property-based fuzz ---------------------------------------------------------


@settings(max_examples=150, deadline=None)
@given(st.lists(st.binary(max_size=200), max_size=8))
def test_random_bytes_never_crash_and_answer_in_ascii(chunks: list[bytes]) -> None:
    s = ConsoleSession(Firmware(), wait_timeout_s=0.0, max_line=64)
    for chunk in chunks:
        out = s.feed(chunk)
        out.decode("ascii")


WORDS = st.sampled_from(
    [
        "gnd",
        "stp",
        "stp+",
        "stp-",
        "inp",
        "cap",
        "off",
        "c",
        "linear",
        "half-cosine",
        "current-limited",
        "overtemp",
        "nan",
        "inf",
        "-1",
        "OK",
        "ERROR",
        "",
    ]
)
NUMBERS = st.one_of(
    st.integers(-10, 100_000).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(-50, 400).map(lambda v: f"{v:.3f}"),
)
AXES = st.sampled_from(["1", "2", "3", "4", "0", "-1", "x"])


@st.composite
def command_lines(draw: st.DrawFn) -> str:
    verb = draw(st.sampled_from([*AXIS_VERBS, "echo", "ver", "gettick", "help", "nonsense"]))
    if verb in ("setpu", "setpd"):
        values = draw(st.lists(st.integers(-5, 260), min_size=250, max_size=258))
        return f"{verb} 1 " + " ".join(map(str, values))
    args = draw(st.lists(st.one_of(NUMBERS, WORDS), max_size=3))
    return " ".join([verb, draw(AXES), *args])


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(command_lines(), min_size=1, max_size=25))
def test_fuzzed_commands_keep_the_dac_stream_inside_voltage_slew_and_current_limits(lines: list[str]) -> None:
    fw = Firmware(FirmwareConfig(dac_buffer_s=0.003))
    stream: list[np.ndarray] = []
    fw.add_sink(lambda axis, first, volts: stream.append(volts.copy()))
    clock = VirtualClock()
    s = ConsoleSession(fw, wait_timeout_s=0.0)
    s.feed(b"echo off\r\nsetm 1 stp\r\nsetv 1 200\r\nstepu 1 c\r\n")
    for line in lines:
        out = s.feed(line.encode() + b"\r\n").decode("ascii").split("\r\n")
        assert out[-1] == "" and TERMINATOR.match(out[-2])
        fw.run(clock, max_ticks=3)
    amp, c = fw.config.amplifier, fw.config.load_capacitance_f
    dt = 1.0 / fw.sample_rate
    for volts in stream:
        assert volts.min() >= amp.v_min_v and volts.max() <= amp.v_max_v
    # consecutive blocks of one axis are contiguous; check slopes inside and across blocks
    per_axis = [np.concatenate(stream[k :: fw.config.axes]) for k in range(fw.config.axes)]
    for volts in per_axis:
        slope = np.abs(np.diff(volts)) / dt
        assert slope.max(initial=0.0) <= amp.slew_rate_v_per_s * (1 + 1e-9)
        assert (c * slope).max(initial=0.0) <= amp.current_limit_a * (1 + 1e-9)


@pytest.fixture(scope="module")
def tcp_console() -> Iterator[TcpConsoleServer]:
    fw = Firmware()
    server = TcpConsoleServer("127.0.0.1", 0, lambda _source: ConsoleSession(fw, password="123456"))
    yield server
    server.close()


def _still_answers(port: int) -> bool:
    sock = _connect(port)
    try:
        _read_until(sock, b"code: ")
        sock.sendall(b"123456\r\necho off\r\ngetm 1\r\n")
        return b"mode = gnd\r\nOK\r\n" in _read_until(sock, b"gnd\r\nOK\r\n")
    finally:
        sock.close()


@pytest.mark.timeout(120)
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    st.lists(
        st.one_of(
            st.binary(max_size=300), st.just(b"123456\r\n"), st.just(b"q" * 70_000), st.just(b"stepu 1 5\r\n")
        ),
        max_size=6,
    )
)
def test_tcp_fuzz_then_disconnect_mid_line_leaves_the_server_answering(
    tcp_console: TcpConsoleServer, chunks: list[bytes]
) -> None:
    sock = _connect(tcp_console.port)
    with contextlib.suppress(OSError):  # the server closes after three failed logins
        for chunk in chunks:
            sock.sendall(chunk)
    sock.close()
    assert _still_answers(tcp_console.port)
