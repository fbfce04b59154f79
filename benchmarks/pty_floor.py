"""The floor of the link benchmarks: a separate process answering each line on a pty at once.

A benchmark script calls :func:`serve` when started with ``--floor`` and uses
:func:`floor_pty` to start itself that way; the ratio against it isolates what
firmware_sim adds to the pty, pyserial/python-can and the client.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tty
from collections.abc import Callable, Iterator
from contextlib import contextmanager

FLAG = "--floor"


def serve(separator: bytes, reply: Callable[[bytes], bytes]) -> None:
    """Open a pty, print its path, answer every ``separator``-ended line; runs until killed."""
    master, slave = os.openpty()
    tty.setraw(slave)
    print(os.ttyname(slave), flush=True)
    pending = b""
    while True:
        pending += os.read(master, 4096)
        *lines, pending = pending.split(separator)
        if lines:
            os.write(master, b"".join(reply(line) for line in lines))


@contextmanager
def floor_pty(script: str) -> Iterator[str]:
    """Run ``script --floor`` as a separate process; yields the pty path it serves."""
    process = subprocess.Popen([sys.executable, script, FLAG], stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None
        yield process.stdout.readline().strip()
    finally:
        process.kill()
        process.wait()
