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
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from feeder.errors import FeederError, InputError

PR_SET_PDEATHSIG = 1
READY_TIMEOUT_S = 30.0
STDERR_LINES_KEPT = 20


class LaunchError(FeederError, RuntimeError):
    """firmware_sim did not start (exited, or no ready line in time)."""


def _die_with_parent() -> None:
    """Runs in the child before exec: SIGTERM when the parent dies (Linux)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)


class Simulator:
    """A running firmware_sim; ``endpoints`` is the ready line's endpoint map.

    Its stderr goes to ``log_path`` (appended; None keeps its last lines in memory);
    either way a :class:`LaunchError` quotes the child's last stderr line.  Stdout after
    the ready line is drained so the child never blocks on a full pipe.  With
    ``timeout_s=None`` the constructor only starts the child (it loads while the caller
    works); :meth:`wait_ready` then reads its ready line.
    """

    def __init__(
        self, args: Sequence[str], log_path: Path | None = None, timeout_s: float | None = READY_TIMEOUT_S
    ) -> None:
        self.command = [sys.executable, "-m", "firmware_sim", *args]
        self.log_path = log_path
        self._stderr_lines: deque[str] = deque(maxlen=STDERR_LINES_KEPT)
        log = open(log_path, "ab") if log_path is not None else subprocess.PIPE  # noqa: SIM115
        self._log_start = log.tell() if log_path is not None else 0  # type: ignore[union-attr]
        try:
            self.process = subprocess.Popen(
                self.command,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=log,
                preexec_fn=_die_with_parent,
                env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )
        finally:
            if log_path is not None:
                log.close()  # type: ignore[union-attr]
        self._stderr_reader: threading.Thread | None = None
        if log_path is None:
            self._stderr_reader = threading.Thread(
                target=self._keep_stderr_tail, name="firmware_sim-stderr", daemon=True
            )
            self._stderr_reader.start()
        self.ready: dict[str, Any] = {}
        self.endpoints: dict[str, Any] = {}
        if timeout_s is not None:
            self.wait_ready(timeout_s)

    def wait_ready(self, timeout_s: float = READY_TIMEOUT_S) -> None:
        """Read the ready line (once) and take the endpoints; :class:`LaunchError` (the child
        stopped) when it exits first or sends none within ``timeout_s``."""
        if self.ready:
            return
        self.ready = self._read_ready(timeout_s)
        self.endpoints = dict(self.ready.get("endpoints", {}))
        threading.Thread(target=self._drain, name="firmware_sim-stdout", daemon=True).start()

    def _keep_stderr_tail(self) -> None:
        """Read the child's stderr (no log file) and keep its last lines for errors."""
        assert self.process.stderr is not None
        with contextlib.suppress(OSError, ValueError):
            for line in self.process.stderr:
                self._stderr_lines.append(line.decode(errors="replace").rstrip())

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
                    raise LaunchError(
                        f"firmware_sim sent no ready line within {timeout_s:g} s (its first start after "
                        "an install or a change to the plant's kernels compiles them for about a minute: "
                        "`python -m feeder.plant.warm_kernels` does it ahead; `make` too)"
                    )
                if not selector.select(remaining):
                    continue
                line = self.process.stdout.readline()
                if not line:
                    err = self._stderr_tail()
                    self.stop()
                    if self.process.returncode == 2:  # its bad input: the arguments it was given
                        reason = err.removeprefix("firmware_sim: error: ")
                        raise InputError("firmware_sim", f"refused its arguments: {reason}")
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
        if self.log_path is not None:  # only what this child wrote
            with open(self.log_path, "rb") as log:
                log.seek(self._log_start)
                lines = log.read().decode(errors="replace").splitlines()
        else:
            if self._stderr_reader is not None:
                self._stderr_reader.join(timeout=2.0)
            lines = list(self._stderr_lines)
        lines = [line.strip() for line in lines if line.strip()]
        code = f"exit code {self.process.returncode}"
        return f"{lines[-1]} ({code})" if lines else code

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
        for stream in (self.process.stdout, self.process.stderr):
            if stream is not None:
                with contextlib.suppress(OSError, ValueError):
                    stream.close()
