"""ANC300-compatible command console (DESIGN §5; reference: docs/anc300-protocol.md).

:class:`ConsoleSession` is one connection's state machine, bytes in → bytes
out, independent of the transport (TCP, pty): line assembly (CR, LF or CRLF;
lines longer than ``max_line`` are refused), optional password login, echo and
prompt, and the command interpreter that calls the firmware's axis API.  Every
reply is zero or more data lines and then ``OK`` or ``<message>``/``ERROR``;
all lines end in CRLF; numbers are plain fixed point.
"""

from __future__ import annotations

import hmac
import math
import re
from collections.abc import Callable
from typing import TYPE_CHECKING

from feeder.protocol.anc300 import (
    BY_NAME,
    PATTERN_POINTS,
    UNKNOWN_COMMAND,
    verbs_of,
)
from firmware_sim.axis import Axis
from firmware_sim.faults import Fault, FirmwareError
from firmware_sim.firmware import Firmware
from firmware_sim.login_throttle import LoginThrottle

if TYPE_CHECKING:
    from firmware_sim.world import TrueStep

CRLF = "\r\n"
PROMPT = "> "
GREETING = "attocube ANC300 compatible controller (firmware_sim)"
VERSION_LINES = (
    "attocube ANC300 controller version 1.1.0-0000 (firmware_sim 0.1.0)",
    "ANC150 compatibillity console",
)
"""``ver``: two data lines, as a real unit answers (``attocube ANC300 controller version
1.1.0-1304 2013-10-17 08:16``, then ``ANC150 compatibillity console``, spelt so: the reply
recorded in qcodes_contrib_drivers' ANC300 simulation); drivers check the first line's start."""
MAX_LINE = 4096
MAX_LOGIN_ATTEMPTS = 3
INTEGER = re.compile(r"[+-]?[0-9]{1,12}")
NUMBER = re.compile(r"[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)?")
"""A decimal number in ASCII (C's ``strtod`` syntax without hex, inf, nan)."""

TrueStepSource = Callable[[Axis], "TrueStep | None"]
"""The plant's true step for an axis' current settings, or None (no plant there)."""


def fixed(value: float, decimals: int = 6) -> str:
    """Plain fixed point, never an exponent: ``fixed(30.5) == '30.500000'``."""
    return f"{value:.{decimals}f}"


def frequency_text(hz: float) -> str:
    """``100`` for whole hertz (what ANC300 clients parse), else fixed point."""
    return str(int(hz)) if float(hz).is_integer() else fixed(hz)


class ConsoleError(Exception):
    """A malformed command line; ``str()`` is the error line."""


class ConsoleSession:
    """One connection's console.

    password: required before any command (``None`` = no login, as on the
        ANC300's USB port).
    true_step: answers the ``simstep`` extension verb (the world's true step).
    wait_timeout_s: longest ``stepw``/``capw`` wait before ERROR (during
        continuous motion they answer ERROR at once: that never ends by itself,
        and a wait would hold a serial console, its only session, until then).
    dialect: ``anc300`` answers only a real ANC300's verbs (every extension gets
        its error reply, ``Unknown command``) and, like the unit, runs whole hertz
        (``setf`` rounds to the nearest) and ends ``getf``'s line with an extra LF;
        ``extended`` adds the extensions
        (:data:`feeder.protocol.anc300.VERBS`) and takes fractional hertz.
    throttle, source: password tries are paced by ``throttle`` under the name
        ``source`` (the peer's address); ``None`` = unpaced (tests).
    """

    def __init__(
        self,
        firmware: Firmware,
        password: str | None = None,
        true_step: TrueStepSource | None = None,
        max_line: int = MAX_LINE,
        wait_timeout_s: float = 600.0,
        dialect: str = "extended",
        throttle: LoginThrottle | None = None,
        source: str = "local",
    ) -> None:
        self.firmware = firmware
        self.verbs = verbs_of(dialect)
        self.as_the_unit = dialect == "anc300"
        self.password = password
        self.true_step = true_step
        self.max_line = max_line
        self.wait_timeout_s = wait_timeout_s
        self.echo = True
        self.logged_in = password is None
        self.closed = False
        self.throttle = throttle
        self.source = source
        self.failed_logins = 0
        self._buffer = bytearray()
        self._discarding = False
        self._skip_lf = False

    # -- bytes in, bytes out --------------------------------------------------

    def greeting(self) -> bytes:
        """What a new connection sees first."""
        if self.logged_in:
            return (GREETING + CRLF).encode()
        return (GREETING + CRLF + "Authorization code: ").encode()

    def feed(self, data: bytes) -> bytes:
        """Consume received bytes; return the bytes to send back.

        After a reply that ends the session (failed logins) ``closed`` is True
        and the rest of ``data`` is ignored.
        """
        out: list[str] = []
        for byte in data:
            if self.closed:
                break
            if self._skip_lf and byte == 0x0A:
                self._skip_lf = False
                continue
            self._skip_lf = byte == 0x0D
            if byte in (0x0A, 0x0D):
                if self._discarding:
                    self._discarding = False
                else:
                    out.append(self._line(bytes(self._buffer)))
                self._buffer.clear()
            elif not self._discarding:
                self._buffer.append(byte)
                if len(self._buffer) > self.max_line:
                    self._buffer.clear()
                    self._discarding = True
                    out.append(self._reply([], "Line too long"))
        return "".join(out).encode("ascii", errors="replace")

    # -- one line -------------------------------------------------------------

    def _line(self, raw: bytes) -> str:
        text = raw.decode("utf-8", errors="replace").strip()
        if not self.logged_in:
            return self._login(text)
        self.firmware.host_activity()
        echoed = text + CRLF if self.echo else ""
        try:
            lines = self._execute(text)
        except (ConsoleError, FirmwareError) as exc:
            return echoed + self._reply([], str(exc))
        return echoed + self._reply(lines, None)

    def _reply(self, lines: list[str], error: str | None) -> str:
        body = "".join(line + CRLF for line in lines)
        if error is not None:
            body += error + CRLF + "ERROR" + CRLF
        else:
            body += "OK" + CRLF
        return body + (PROMPT if self.echo else "")

    def _login(self, text: str) -> str:
        masked = "*" * len(text) + CRLF
        if self._password_ok(text):
            self.logged_in = True
            return masked + "Authorization success" + CRLF
        self.failed_logins += 1
        if self.failed_logins >= MAX_LOGIN_ATTEMPTS:
            self.closed = True
            return masked + "Authorization failed" + CRLF
        return masked + "Authorization failed" + CRLF + "Authorization code: "

    def _password_ok(self, text: str) -> bool:
        assert self.password is not None
        expected = self.password.encode()

        def check() -> bool:  # constant time: the reply's timing tells nothing
            return hmac.compare_digest(text.encode(), expected)

        return check() if self.throttle is None else self.throttle.attempt(self.source, check)

    # -- interpreter ----------------------------------------------------------

    def _execute(self, text: str) -> list[str]:
        words = text.split()
        if not words:
            return []
        verb, args = words[0].lower(), words[1:]
        if verb not in self.verbs:
            raise ConsoleError(UNKNOWN_COMMAND)
        fw = self.firmware
        if verb == "echo":
            _arity(args, 1)
            if args[0] not in ("on", "off"):
                raise ConsoleError("Expected on or off")
            self.echo = args[0] == "on"
            return []
        if verb == "ver":
            _arity(args, 0)
            return list(VERSION_LINES)
        if verb == "getcser":
            _arity(args, 0)
            return [f"serialnumber = {fw.config.serial_number}"]
        if verb == "help":
            return [f"{name} {BY_NAME[name].usage}".rstrip() for name in BY_NAME if name in self.verbs]
        if verb == "gettick":
            _arity(args, 0)
            return [
                f"{key[:-2]} = {fixed(value * 1e6, 3)} us" if key.endswith("_s") else f"{key} = {value}"
                for key, value in fw.tick_summary().items()
            ]
        handler = AXIS_VERBS.get(verb)
        if handler is None:
            raise ConsoleError(UNKNOWN_COMMAND)
        if not args:
            raise ConsoleError("Missing axis number")
        return handler(self, fw.axis(_integer(args[0], "axis")), args[1:])

    # -- axis verbs (each: session, axis, remaining args → data lines) --------

    def _setm(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 1)
        axis.set_mode(args[0])
        return []

    def _getm(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        return [f"mode = {axis.status().mode}"]

    def _setf(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 1)
        hz = _number(args[0], "frequency")
        axis.set_frequency(float(round(hz)) if self.as_the_unit else hz)
        return []

    def _getf(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        line = f"frequency = {frequency_text(axis.status().frequency_hz)} Hz"
        # the unit ends this one line with an extra LF before its CRLF (pymeasure's recorded
        # exchange; qcodes: "Response for getf is terminated with '\n'")
        return [line + "\n"] if self.as_the_unit else [line]

    def _setv(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 1)
        axis.set_amplitude(_number(args[0], "voltage"))
        return []

    def _getv(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        return [f"voltage = {fixed(axis.status().amplitude_v)} V"]

    def _seta(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 1)
        axis.set_offset(_number(args[0], "offset"))
        return []

    def _geta(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        return [f"voltage = {fixed(axis.status().offset_v)} V"]

    def _geto(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        return [f"voltage = {fixed(axis.status().output_v)} V"]

    def _step(self, axis: Axis, args: list[str], up: bool) -> list[str]:
        if len(args) > 1:
            raise ConsoleError("Wrong number of arguments")
        count = args[0] if args else "1"
        if count.lower() == "c" or count == "0":  # stepu 0 = continuous, as on real units
            axis.run_continuous(up)
        else:
            n = _integer(count, "steps")
            if n < 0:
                raise ConsoleError("Step count must be positive")
            axis.step(n if up else -n)
        return []

    def _stepu(self, axis: Axis, args: list[str]) -> list[str]:
        return self._step(axis, args, up=True)

    def _stepd(self, axis: Axis, args: list[str]) -> list[str]:
        return self._step(axis, args, up=False)

    def _stop(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        axis.stop()
        return []

    def _wait(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        if not axis.wait_idle(self.wait_timeout_s):
            raise ConsoleError("Timeout waiting for the axis")
        return []

    def _getc(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        return [f"capacitance = {fixed(axis.capacitance_f * 1e9)} nF"]

    def _setp(self, axis: Axis, args: list[str], up: bool) -> list[str]:
        _arity(args, PATTERN_POINTS)
        axis.set_pattern(up, [_integer(v, "pattern") for v in args])
        return []

    def _setpu(self, axis: Axis, args: list[str]) -> list[str]:
        return self._setp(axis, args, up=True)

    def _setpd(self, axis: Axis, args: list[str]) -> list[str]:
        return self._setp(axis, args, up=False)

    def _getpu(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        return [str(v) for v in axis.pattern(True)]

    def _getpd(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        return [str(v) for v in axis.pattern(False)]

    def _getser(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        return [f"serialnumber = {self.firmware.config.serial_number}A{axis.number}"]

    # extensions

    def _setfb(self, axis: Axis, args: list[str]) -> list[str]:
        if len(args) not in (1, 2):
            raise ConsoleError("Wrong number of arguments")
        axis.set_flyback(args[0], _number(args[1], "flyback") if len(args) == 2 else 0.0)
        return []

    def _getfb(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        status = axis.status()
        return [f"flybackshape = {status.flyback_shape}", f"flyback = {fixed(status.flyback_s, 9)} s"]

    def _getcnt(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        return [f"steps = {axis.status().step_counter}"]

    def _getst(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        s = axis.status()
        return [
            f"mode = {s.mode}",
            f"frequency = {frequency_text(s.frequency_hz)} Hz",
            f"voltage = {fixed(s.amplitude_v)} V",
            f"steps = {s.step_counter}",
            f"moving = {int(s.moving)}",
            f"faults = {s.fault_word}",
            f"faultnames = {','.join(s.faults) or 'none'}",
        ]

    def _clrf(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        axis.clear_faults()
        return []

    def _injf(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 1)
        try:
            bit = Fault[args[0].upper()]
        except KeyError:
            raise ConsoleError("Unknown fault") from None
        axis.inject_fault(bit)
        return []

    def _simstep(self, axis: Axis, args: list[str]) -> list[str]:
        _arity(args, 0)
        step = self.true_step(axis) if self.true_step is not None else None
        if step is None:
            raise ConsoleError("No plant on this axis")
        return [
            f"stepup = {fixed(step.up_m, 12)} m",
            f"stepdown = {fixed(step.down_m, 12)} m",
            f"stepscatter = {fixed(step.scatter)}",
        ]


def _arity(args: list[str], n: int) -> None:
    if len(args) != n:
        raise ConsoleError("Wrong number of arguments")


def _number(text: str, name: str) -> float:
    """An ASCII decimal number (:data:`NUMBER`; not ``1_0``, non-ASCII digits, inf, nan);
    ``-0`` is 0."""
    if NUMBER.fullmatch(text) is None or not math.isfinite(value := float(text)):
        raise ConsoleError(f"Invalid number for {name}")
    return value + 0.0  # -0.0 + 0.0 == +0.0


def _integer(text: str, name: str) -> int:
    if INTEGER.fullmatch(text) is None:
        raise ConsoleError(f"Invalid integer for {name}")
    return int(text)


AxisVerb = Callable[[ConsoleSession, Axis, list[str]], list[str]]

AXIS_VERBS: dict[str, AxisVerb] = {
    "setm": ConsoleSession._setm,
    "getm": ConsoleSession._getm,
    "setf": ConsoleSession._setf,
    "getf": ConsoleSession._getf,
    "setv": ConsoleSession._setv,
    "getv": ConsoleSession._getv,
    "seta": ConsoleSession._seta,
    "geta": ConsoleSession._geta,
    "geto": ConsoleSession._geto,
    "stepu": ConsoleSession._stepu,
    "stepd": ConsoleSession._stepd,
    "stop": ConsoleSession._stop,
    "stepw": ConsoleSession._wait,
    "getc": ConsoleSession._getc,
    "capw": ConsoleSession._wait,
    "setpu": ConsoleSession._setpu,
    "setpd": ConsoleSession._setpd,
    "getpu": ConsoleSession._getpu,
    "getpd": ConsoleSession._getpd,
    "getser": ConsoleSession._getser,
    "setfb": ConsoleSession._setfb,
    "getfb": ConsoleSession._getfb,
    "getcnt": ConsoleSession._getcnt,
    "getst": ConsoleSession._getst,
    "clrf": ConsoleSession._clrf,
    "injf": ConsoleSession._injf,
    "simstep": ConsoleSession._simstep,
}
