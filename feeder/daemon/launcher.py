"""Start ``python -m firmware_sim`` as a separate program and read its ready line.

The simulator prints one JSON line ``{"ready": true, "endpoints": {...}}`` on
stdout when its endpoints (console pty, sensor port, slcan pty) are up.  The
child gets ``PR_SET_PDEATHSIG`` so it ends with the daemon even when the
daemon is killed with SIGKILL.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import selectors
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from feeder.errors import FeederError

PR_SET_PDEATHSIG = 1
READY_TIMEOUT_S = 30.0


class LaunchError(FeederError, RuntimeError):
    """firmware_sim did not start (exited, or no ready line in time)."""


def _die_with_parent() -> None:
    """Runs in the child before exec: SIGTERM when the parent dies (Linux)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)


class Simulator:
    """A running firmware_sim; ``endpoints`` is the ready line's endpoint map.

    Its stderr goes to ``log_path`` (appended; None discards it); stdout after
    the ready line is drained so the child never blocks on a full pipe.
    """

    def __init__(self, args: Sequence[str], log_path: Path | None = None,
                 timeout_s: float = READY_TIMEOUT_S) -> None:
        self.command = [sys.executable, "-m", "firmware_sim", *args]
        self.log_path = log_path
        log = open(log_path, "ab") if log_path is not None else subprocess.DEVNULL  # noqa: SIM115
        try:
            self.process = subprocess.Popen(
                self.command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log,
                preexec_fn=_die_with_parent, env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )
        finally:
            if log_path is not None:
                log.close()  # type: ignore[union-attr]
        self.ready = self._read_ready(timeout_s)
        self.endpoints: dict[str, Any] = dict(self.ready.get("endpoints", {}))
        threading.Thread(target=self._drain, name="firmware_sim-stdout", daemon=True).start()

    def _drain(self) -> None:
        assert self.process.stdout is not None
        with contextlib.suppress(OSError, ValueError):
            for _ in self.process.stdout:
                pass

    def _read_ready(self, timeout_s: float) -> dict[str, Any]:
        assert self.process.stdout is not None
        selector = selectors.DefaultSelector()
        selector.register(self.process.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + timeout_s
        try:
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    self.stop()
                    raise LaunchError(f"firmware_sim sent no ready line within {timeout_s:g} s")
                if not selector.select(remaining):
                    continue
                line = self.process.stdout.readline()
                if not line:
                    err = self._stderr_tail()
                    self.stop()
                    raise LaunchError(f"firmware_sim exited before it was ready: {err}")
                try:
                    obj = json.loads(line)
                except json.JSONDecodeError:
                    continue
                if isinstance(obj, dict) and obj.get("ready") is True:
                    return obj
        finally:
            selector.close()

    def _stderr_tail(self) -> str:
        try:
            self.process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            return "(still running)"
        text = ""
        if self.log_path is not None:
            text = self.log_path.read_text(errors="replace").strip()
        return text.splitlines()[-1] if text else f"exit code {self.process.returncode}"

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self, timeout_s: float = 5.0) -> None:
        """SIGTERM (clean shutdown, output grounded), SIGKILL if it lingers."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self.process.stdout is not None:
            with contextlib.suppress(OSError, ValueError):
                self.process.stdout.close()
