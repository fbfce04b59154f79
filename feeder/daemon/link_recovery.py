"""Recovering from a lost amplifier link or camera, for the daemon (:mod:`feeder.daemon.service`).

The loop's policy ends the move (``fault``) when a link is lost; :meth:`LinkRecovery.link_lost`
then records the fault, refuses the queued moves, grounds the output where the lost amplifier
link still answers (never through a dead simulator's pty), frees the port, and starts a thread
that reopens the link with backoff (:mod:`~feeder.daemon.reconnect`).  A new amplifier link is
grounded before the loop gets it; a camera is back only once it delivers a reading.  No move
resumes by itself.  When the embedded simulator died, its death leads the fault's message.
"""

from __future__ import annotations

import contextlib
import logging
import subprocess
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from feeder.daemon.control_loop import ControlLoop, Job
from feeder.daemon.executor import per_axis
from feeder.daemon.located_calibration import LocatedCalibration
from feeder.daemon.reconnect import Outage, first_reading
from feeder.drivers.amplifier import Amplifier
from feeder.drivers.sensor import SensorLost
from feeder.errors import FeederError

if TYPE_CHECKING:
    from feeder.daemon.service import Links

log = logging.getLogger(__name__)

SIMULATOR_EXIT_S = 0.2
"""How long a lost link waits for the embedded simulator's exit to be known, to name it as the
cause (the camera's socket closes a moment before the process can be reaped)."""

KEPT_FAULTS = 20
"""The latest faults kept for ``status``."""


class LinkRecovery:
    """The daemon's lost links: the faults' records and the reconnect threads.

    ``lock`` is the daemon's: it guards :attr:`faults` and :attr:`reconnecting` (``status`` reads
    them holding it) and the queue that ``take_queue`` empties (called holding it); ``refuse``
    answers a job taken from the queue.  ``stopping``: the daemon's shutdown has begun (no
    reconnect starts, a running one gives up).  ``respawns_when_opened``: the links' simulator
    respawns when the amplifier link in use was opened.
    """

    def __init__(
        self,
        links: Links,
        loop: ControlLoop,
        camera_calibration: LocatedCalibration,
        *,
        respawns_when_opened: int,
        sensor_timeout_s: float,
        lock: threading.Lock,
        stopping: threading.Event,
        take_queue: Callable[[], list[Job]],
        refuse: Callable[[Job, str], None],
    ) -> None:
        self.links = links
        self.loop = loop
        self.camera_calibration = camera_calibration
        self.sensor_timeout_s = sensor_timeout_s
        self._respawns_when_opened = respawns_when_opened  # a respawn since: that link is stale
        self._lock = lock
        self._stopping = stopping
        self._take_queue = take_queue
        self._refuse = refuse
        self.faults: list[dict[str, Any]] = []
        """The latest :data:`KEPT_FAULTS` faults: link, message, time, the reconnect's progress."""
        self.reconnecting: set[str] = set()
        """The links being reopened (``amplifier``, ``sensor``)."""

    def _respawns(self) -> int:
        """How often the links restarted the embedded simulator (0 on hardware)."""
        return getattr(self.links, "respawns", 0)

    def simulator_died(self, wait_s: float = 0.0) -> str | None:
        """That the embedded simulator behind the links died, or None (alive, or hardware);
        ``wait_s``: how long to wait for its exit (a dying process closes its sockets, which
        the links notice, a moment before it can be reaped)."""
        simulator = getattr(self.links, "simulator", None)
        if simulator is None:
            return None
        if wait_s > 0 and simulator.alive():
            with contextlib.suppress(subprocess.TimeoutExpired):
                simulator.process.wait(timeout=wait_s)
        if simulator.alive():
            return None
        code = simulator.process.returncode
        return f"the embedded simulator (firmware_sim, pid {simulator.process.pid}) died (exit code {code})"

    def ground_lost_link(self) -> str:
        """Ground every axis where the lost amplifier link still answers (never through a stale
        simulator pty: another program may own that path now); what became of the output."""
        # the simulator's death is known before the respawn that counts it: its pty path is
        # already free for another program to take
        respawned = self._respawns() != self._respawns_when_opened
        if respawned or self.simulator_died() is not None:
            return "not grounded (a new simulator: the old one's output died with it)"
        failed = []
        for axis, amplifier in self.loop.amplifiers.items():
            try:
                amplifier.ground()
            except (FeederError, OSError) as err:
                failed.append(f"{axis}: {err}")
        return f"the output could not be grounded ({'; '.join(failed)})" if failed else "output grounded"

    def link_lost(self, kind: str, message: str) -> None:
        """The loop's ``on_fault`` (on a thread of its own, not the tick's): the ``kind`` link
        (``amplifier`` or ``sensor``) was lost with ``message``; record it and reconnect."""
        cause = self.simulator_died(SIMULATOR_EXIT_S)  # on this thread, not the tick's: it waits
        if cause is not None and not message.startswith(cause):
            message = f"{cause}: {message}"
        if kind != "amplifier":  # the policy stops and grounds the output through the executor
            log.error("%s link lost: %s; grounding the output, reconnecting", kind, message)
        record: dict[str, Any] = {"link": kind, "message": message, "time_s": time.time()}
        with self._lock:
            self.faults.append(record)
            del self.faults[:-KEPT_FAULTS]
            if kind in self.reconnecting or self._stopping.is_set():
                if kind == "amplifier":
                    log.error("amplifier link lost: %s (reconnecting already)", message)
                return
            self.reconnecting.add(kind)
            queued = self._take_queue()
        for job in queued:
            self._refuse(job, f"{kind} lost: {message}")
        if kind == "amplifier":  # ground where the link still allows it, then free the port
            log.error("amplifier link lost: %s; %s, reconnecting", message, self.ground_lost_link())
            with contextlib.suppress(FeederError, OSError):
                release_amplifiers(self.loop.amplifiers)
        thread = threading.Thread(
            target=self._reconnect, args=(kind, record), name=f"reconnect-{kind}", daemon=True
        )
        thread.start()

    def _reconnect(self, kind: str, record: dict[str, Any]) -> None:
        """Re-open the lost link with exponential backoff (:class:`.Outage`); progress goes into
        ``record``."""
        outage = Outage(kind, time.monotonic())
        while not self._stopping.wait(outage.delay_s):
            try:
                if kind == "amplifier":
                    amps = per_axis(self.links.open_amplifier())
                    with contextlib.ExitStack() as undo:  # a link that cannot ground is closed
                        undo.callback(release_amplifiers, amps)
                        for amp in amps.values():
                            amp.ground()
                        undo.pop_all()
                    self.loop.replace_amplifier(amps)
                    self._respawns_when_opened = self._respawns()
                else:
                    self._reopen_sensor()
            except Exception as err:
                # this reconnect thread's one boundary: whatever stops a link from opening
                # (drivers, python-can, the launcher) is logged now and then and retried with
                # backoff; the thread must outlive it
                line = outage.failed(str(err), time.monotonic())
                if line is not None:
                    log.log(logging.INFO if outage.attempts == 1 else logging.WARNING, "%s", line)
                with self._lock:
                    record["reconnect_attempts"] = outage.attempts
                    record["last_error"] = f"{type(err).__name__}: {err}"
                continue
            line = outage.restored(time.monotonic())
            with self._lock:
                record["reconnected_after_attempts"] = outage.attempts
            log.info("%s", line)
            break
        with self._lock:
            self.reconnecting.discard(kind)
        if self._respawns() != self._respawns_when_opened:
            # the simulator behind the amplifier link was restarted: that link is stale
            self.loop.amplifier_lost("firmware_sim was restarted; reopening its new console")

    def _reopen_sensor(self) -> None:
        """Open the sensor again; it is the loop's (the fault over) only once it has delivered a
        first reading: a link that opens but sends nothing raises :class:`SensorLost`."""
        stored, calibration = self.camera_calibration.read()
        sensor = self.links.open_sensor(calibration)
        first = first_reading(sensor, self.sensor_timeout_s)
        if self._stopping.is_set():  # shut down meanwhile: the loop reads no more
            sensor.close()
            raise SensorLost("daemon shutting down")
        self.loop.replace_sensor(sensor, first)
        self.camera_calibration.use(stored, calibration)


def release_amplifiers(amplifiers: dict[str, Amplifier]) -> None:
    """Release the drivers, outputs untouched (a group of axes on one link releases it once)."""
    release = getattr(amplifiers, "release", None)
    if callable(release):
        release()
        return
    for amplifier in amplifiers.values():
        amplifier.close()
