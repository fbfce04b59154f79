"""A Lawicel SLCAN (CAN-over-serial) adapter emulated on a pty.

The host opens the pty's slave path exactly as it would open a USB-serial CAN
adapter::

    can.Bus(interface="slcan", channel=PTY_PATH, bitrate=500000, sleep_after_open=0)

and every frame it sends comes out on the adapter's CAN side, a python-can bus
(in ``firmware_sim`` an endpoint of :class:`~firmware_sim.can_wire.CanWire`, the
segment the CANopen nodes share, where a node answers in the thread that
delivered the request).  Frames seen on the CAN side go to the host while the
channel is open.

Protocol (Lawicel CANUSB / CAN232 ASCII, the subset python-can and common tools
use); every command ends in CR (LF is accepted too), replies end in CR, errors
are a lone BEL (0x07):

==============  =========================================  ==================
command         meaning                                    reply
==============  =========================================  ==================
``Sn``          bit rate n = 0..8 (10k..1M), channel closed  CR
``sxxyy``       SJA1000 BTR0/BTR1, channel closed          CR
``O`` / ``L``   open / open listen-only                    CR (BEL if open)
``C``           close (idempotent; drops queued output)    CR
``tiiildd..``   send standard frame, ``T`` extended        ``z`` / ``Z`` CR
``riiil``       send remote frame, ``R`` extended          ``z`` / ``Z`` CR
``F``           status flags (bit 3 data overrun,          ``Fxx`` CR
                bit 7 bus error: a frame could not be sent)
``V`` ``v`` ``N``  hardware/software version, serial number  ``V1013`` ...
``Zn``          time stamps off/on (ms, 4 hex digits)      CR
``Mxxxxxxxx``   acceptance code / ``m`` mask (ignored)     CR
==============  =========================================  ==================

Anything else -- unknown letters, wrong lengths, non-hex digits, DLC > 8,
identifiers out of range, non-ASCII bytes, lines over 32 bytes, frames while
the channel is closed -- is answered with BEL and changes nothing.  Empty lines
are ignored (tools send a few CRs to resynchronise).

The bus bit rate is accepted but not simulated: frames move as fast as the pty
and the two programs allow.  When the host stops reading, output is queued up to
:data:`MAX_QUEUED_BYTES`; further frames are dropped and the overrun flag set,
as a real adapter's receive FIFO overflows.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import termios
import threading
import time
import tty

import can

from firmware_sim.can_wire import WireBus

OK = b"\r"
ERROR = b"\a"
MAX_LINE_BYTES = 32
MAX_QUEUED_BYTES = 65536
FLAG_DATA_OVERRUN = 0x08
FLAG_BUS_ERROR = 0x80
HARDWARE_VERSION = "10"
SOFTWARE_VERSION = "13"
BITRATES = {
    0: 10_000,
    1: 20_000,
    2: 50_000,
    3: 100_000,
    4: 125_000,
    5: 250_000,
    6: 500_000,
    7: 800_000,
    8: 1_000_000,
}
_HEX = frozenset(b"0123456789ABCDEFabcdef")


def _hex_value(field: bytes) -> int | None:
    """The value of a non-empty field of hex digits, None if it is anything else."""
    if not field or not set(field) <= _HEX:
        return None
    return int(field, 16)


class SlcanAdapter:
    """The adapter's protocol state: one command line in, one reply out.

    ``bus`` is the CAN side; :meth:`handle_line` sends the frames the host asks
    for on it, :meth:`frame_line` formats a frame from it for the host.
    """

    def __init__(self, bus: can.BusABC, serial_number: str = "FS01") -> None:
        self.bus = bus
        self.serial_number = serial_number
        self.bitrate = 500_000
        self.is_open = False
        self.listen_only = False
        self.timestamps = False
        self.flags = 0
        self.opened_at = 0.0
        self._start = time.monotonic()

    def handle_line(self, line: bytes) -> bytes:
        """Execute one command (without its CR), sending its frame if it is one; the reply."""
        reply, frame = self.command(line)
        if frame is not None and not self.send(frame):
            return ERROR
        return reply

    def command(self, line: bytes) -> tuple[bytes, can.Message | None]:
        """Execute one command (without its CR) but leave the sending to the caller:
        the reply, and the frame to send if the line is a valid transmit command."""
        if not line:
            return b"", None
        if len(line) > MAX_LINE_BYTES or not line.isascii():
            return ERROR, None
        verb, arg = line[:1], line[1:]
        if verb in b"tTrR":
            frame = self._frame(verb, arg)
            if frame is None:
                return ERROR, None
            return (b"Z\r" if frame.is_extended_id else b"z\r"), frame
        return self._setting(verb, arg), None

    def send(self, frame: can.Message) -> bool:
        """Put ``frame`` on the CAN side; False (and the bus-error flag) if that failed."""
        try:
            self.bus.send(frame, timeout=0.1)
        except can.CanError:
            self.flags |= FLAG_BUS_ERROR
            return False
        return True

    def _setting(self, verb: bytes, arg: bytes) -> bytes:
        """The reply to any command but a transmit."""
        if verb in (b"O", b"L"):
            if self.is_open or arg:
                return ERROR
            self.is_open, self.listen_only = True, verb == b"L"
            self.opened_at = time.time()
            return OK
        if verb == b"C" and not arg:
            self.is_open = self.listen_only = False
            return OK
        if verb == b"S":
            code = _hex_value(arg) if len(arg) == 1 else None
            if self.is_open or code not in BITRATES:
                return ERROR
            self.bitrate = BITRATES[code]
            return OK
        if verb == b"s":
            return ERROR if self.is_open or len(arg) != 4 or _hex_value(arg) is None else OK
        if verb == b"Z" and arg in (b"0", b"1"):
            self.timestamps = arg == b"1"
            return OK
        if verb in b"Mm" and len(arg) == 8 and _hex_value(arg) is not None:
            return OK
        if verb == b"F" and not arg:
            flags, self.flags = self.flags, 0
            return f"F{flags:02X}\r".encode()
        if verb == b"V" and not arg:
            return f"V{HARDWARE_VERSION}{SOFTWARE_VERSION}\r".encode()
        if verb == b"v" and not arg:
            return f"v{SOFTWARE_VERSION}\r".encode()
        if verb == b"N" and not arg:
            return f"N{self.serial_number}\r".encode()
        return ERROR

    def _frame(self, verb: bytes, arg: bytes) -> can.Message | None:
        """The frame a transmit command asks for; None if the line is malformed or
        the channel is not open for sending."""
        extended = verb in b"TR"
        remote = verb in b"rR"
        id_digits = 8 if extended else 3
        can_id = _hex_value(arg[:id_digits])
        dlc = _hex_value(arg[id_digits : id_digits + 1])
        if can_id is None or dlc is None or dlc > 8 or can_id > (0x1FFFFFFF if extended else 0x7FF):
            return None
        payload = arg[id_digits + 1 :]
        if remote:
            if payload:
                return None
            data = b""
        else:
            if len(payload) != 2 * dlc or (payload and _hex_value(payload) is None):
                return None
            data = bytes.fromhex(payload.decode())
        if not self.is_open or self.listen_only:
            return None
        return can.Message(
            arbitration_id=can_id, is_extended_id=extended, is_remote_frame=remote, dlc=dlc, data=data
        )

    def frame_line(self, message: can.Message) -> bytes | None:
        """The line announcing ``message`` to the host; None while closed or for
        frames SLCAN cannot carry (error frames, CAN FD)."""
        if not self.is_open or message.is_error_frame or message.is_fd:
            return None
        if message.is_extended_id:
            head = f"{'R' if message.is_remote_frame else 'T'}{message.arbitration_id:08X}"
        else:
            head = f"{'r' if message.is_remote_frame else 't'}{message.arbitration_id:03X}"
        text = f"{head}{message.dlc:d}"
        if not message.is_remote_frame:
            text += bytes(message.data).hex().upper()
        if self.timestamps:
            text += f"{int((time.monotonic() - self._start) * 1000) % 60000:04X}"
        return text.encode() + OK


class SlcanPty:
    """:class:`SlcanAdapter` served on a pty; :attr:`path` is what the host opens.

    One thread reads command lines from the pty and sends their frames on the
    CAN side (``bus``, owned: :meth:`close` shuts it down).  Frames from the CAN
    side go to the host as they arrive: on a :class:`~firmware_sim.can_wire.WireBus`
    in the sending endpoint's thread (a node's answer leaves in the same thread
    that delivered the request), on any other python-can bus through a second
    thread that receives them.  The slave end stays open here too, so hosts may
    come and go.

    Locking: one lock guards the adapter's state and the output queue; it is
    never held while a frame is sent, so a frame's receivers may answer at once.
    """

    def __init__(self, bus: can.BusABC, serial_number: str = "FS01") -> None:
        self.adapter = SlcanAdapter(bus, serial_number)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()
        self._lock = threading.RLock()  # adapter state and output queue
        self._queued = bytearray()
        self._pty_thread: int | None = None
        self._stopping = threading.Event()
        self._threads = [threading.Thread(target=self._serve_pty, name="slcan-pty", daemon=True)]
        if isinstance(bus, WireBus):
            bus.receiver = self._forward
        else:
            self._threads.append(threading.Thread(target=self._receive_bus, name="slcan-bus", daemon=True))

    def start(self) -> SlcanPty:
        for thread in self._threads:
            thread.start()
        return self

    def close(self) -> None:
        """Stop the threads, shut the CAN side down and release the pty."""
        self._stopping.set()
        os.write(self._wake_w, b"x")
        for thread in self._threads:
            if thread.is_alive():
                thread.join(timeout=2.0)
        self.adapter.bus.shutdown()
        with self._lock:
            for fd in (self._master, self._slave, self._wake_r, self._wake_w):
                with contextlib.suppress(OSError):
                    os.close(fd)
            self._queued.clear()

    def __enter__(self) -> SlcanPty:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _write(self, data: bytes) -> None:
        """Queue ``data`` for the host; dropped, with the overrun flag set, when
        the host has not read the last :data:`MAX_QUEUED_BYTES`.  Written to the
        pty at once, except from the pty thread, which writes all it queued
        for a chunk of input in one go (a request's ``z`` and its answer
        reach the host together, as from an adapter's USB packet)."""
        with self._lock:
            if self._stopping.is_set():
                return
            if len(self._queued) + len(data) > MAX_QUEUED_BYTES:
                self.adapter.flags |= FLAG_DATA_OVERRUN
                return
            was_empty = not self._queued
            self._queued += data
            if threading.get_ident() != self._pty_thread:
                self._flush_locked()
                if was_empty and self._queued:
                    os.write(self._wake_w, b"w")  # the pty thread waits for room on the pty

    def _flush_locked(self) -> None:
        while self._queued:
            try:
                written = os.write(self._master, self._queued)
            except BlockingIOError:
                return
            except OSError as exc:
                if exc.errno in (errno.EIO, errno.EBADF):
                    self._queued.clear()
                    return
                raise
            del self._queued[:written]

    def _forward(self, message: can.Message) -> None:
        """A frame from the CAN side: to the host if the channel is open (and was
        when the frame was sent: a closed adapter heard nothing)."""
        with self._lock:
            if message.timestamp < self.adapter.opened_at:
                return
            text = self.adapter.frame_line(message)
            if text is not None:
                self._write(text)

    def _execute(self, line: bytes) -> None:
        """One command line from the host: reply, then send its frame (if any)."""
        with self._lock:
            if line == b"C":  # a new session starts clean: drop what the host has not read
                self._queued.clear()
                termios.tcflush(self._slave, termios.TCIFLUSH)
            reply, frame = self.adapter.command(line)
            if reply:
                self._write(reply)
        if frame is not None:
            self.adapter.send(frame)

    def _serve_pty(self) -> None:
        self._pty_thread = threading.get_ident()
        line = bytearray()
        overlong = False
        while not self._stopping.is_set():
            with self._lock:
                pending = bool(self._queued)
            readable, writable, _ = select.select(
                [self._master, self._wake_r], [self._master] if pending else [], [], 0.5
            )
            if self._wake_r in readable:
                os.read(self._wake_r, 4096)
            if writable:
                with self._lock:
                    self._flush_locked()
            if self._master not in readable:
                continue
            try:
                chunk = os.read(self._master, 4096)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                return
            for byte in chunk:
                if byte in (0x0D, 0x0A):
                    if overlong:
                        self._write(ERROR)
                    else:
                        self._execute(bytes(line))
                    line.clear()
                    overlong = False
                elif len(line) < MAX_LINE_BYTES + 1:
                    line.append(byte)
                else:
                    overlong = True
            with self._lock:
                self._flush_locked()

    def _receive_bus(self) -> None:
        while not self._stopping.is_set():
            message = self.adapter.bus.recv(timeout=0.2)
            if message is not None:
                self._forward(message)
