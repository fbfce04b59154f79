"""The console's listening socket, bound before the daemon starts anything (no web imports):
a taken ``--http`` port is refused before the simulator starts or a state file is written."""

from __future__ import annotations

import socket

from feeder.errors import InputError

LISTEN_BACKLOG = 128
"""Connections the kernel holds before accept, and the most the event loop accepts at once."""


def listen(host: str, port: int) -> socket.socket:
    """A TCP socket listening on ``host:port`` (port 0: any free one); :class:`InputError` naming
    ``--http`` when it cannot be bound (taken, or an address not of this machine)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(LISTEN_BACKLOG)
    except OSError as err:
        sock.close()
        raise InputError("--http", f"cannot listen on {host}:{port}: {err}") from None
    return sock
