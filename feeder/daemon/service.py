"""The daemon: control loop + state database + move queue, its links recovered when lost.

Requests come over the owner-only Unix socket of :mod:`feeder.daemon.socket_server` and are
answered by :mod:`feeder.daemon.requests`; one move at a time (a second is refused with the
reason, or queued with ``"queue": true``).

Faults: a lost amplifier link or sensor ends the move (``fault``) and is reconnected in the
background (:mod:`~feeder.daemon.link_recovery`); no move resumes by itself.  Moves are
recorded as ``running`` before the first step; a daemon killed mid-move finds them on restart
and marks them ``interrupted``, and reports the position as ``uncertain`` until the sensor
confirms it.
"""

from __future__ import annotations

import collections
import contextlib
import fcntl
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Protocol

from feeder.daemon.camera_moves import LoopPoses, PlateMoves, stop_on_hang_up, summary
from feeder.daemon.control_loop import ControlLoop, Job, JobResult, LoopSettings, Navigator, StepMode
from feeder.daemon.executor import per_axis
from feeder.daemon.jobs import Reading
from feeder.daemon.link_recovery import LinkRecovery, release_amplifiers
from feeder.daemon.located_calibration import STORED, LocatedCalibration
from feeder.daemon.move_records import MoveRecords
from feeder.daemon.quiet_window import QuietWindow
from feeder.daemon.requests import answer
from feeder.daemon.socket_server import SocketServer
from feeder.daemon.status_report import loop_status, waveforms_status
from feeder.daemon.store import Store
from feeder.drivers.amplifier import Amplifier, AmplifierLinkLost
from feeder.drivers.sensor import PositionSensor
from feeder.errors import FeederError, InputError
from feeder.vision.calibration import CameraCalibration
from feeder.vision.offset_moves import MovesStopped, OffsetMoves, measure

log = logging.getLogger(__name__)

CAMERA_MOVES_END_S = 5.0
"""How long the shutdown waits for a camera calibration it stopped to end (its moves stop within
an increment or the frames being averaged, then ground every axis; a finished one is stored)
before it closes the links and the store under it."""


class Links(Protocol):
    """How the daemon reaches its hardware; called again to reconnect."""

    def open_amplifier(self) -> Amplifier | dict[str, Amplifier]: ...

    def open_sensor(self, calibration: CameraCalibration | None = None) -> PositionSensor: ...

    def configured_calibration(self) -> CameraCalibration | None: ...


@dataclass(frozen=True)
class DaemonSetup:
    """Everything the daemon needs besides its links.

    calibration_key: identifies part, support and waveforms, so a learned step
    is only reused for the same combination.
    info: static facts shown by ``status`` (transport, part, ...).
    uncalibrated_camera: why moves wait for a stored camera calibration
    (:meth:`~feeder.daemon.config.CameraConfig.uncalibrated`), None: they need none.
    axis_modes, pose_navigator: for a plate driven in x, y and θ, every axis'
    waveform modes and a factory of the pose navigator (given the learned response
    the store restored, or None); parts: each part's ``id``, ``shape``, ``size_m``;
    plate_moves: what a camera calibration from plate moves needs (a plane with a camera).
    """

    modes: dict[str, StepMode]
    loop: LoopSettings
    database_path: Path
    socket_path: Path
    calibration_key: str
    info: dict[str, Any]
    sensor_timeout_s: float = 1.0
    axis_modes: dict[str, dict[str, StepMode]] | None = None
    pose_navigator: Callable[[dict[str, Any] | None], Navigator] | None = None
    parts: tuple[dict[str, Any], ...] = ()
    uncalibrated_camera: str | None = None
    plate_moves: PlateMoves | None = None


def lock_state(database_path: Path) -> IO[bytes]:
    """An exclusive lock beside the database (released when the process dies, even by SIGKILL).

    Raises :class:`InputError` when another daemon holds it, or the directory cannot be made or
    written (a file of that name, no permission).
    """
    lock_path = database_path.with_name(database_path.name + ".lock")
    try:
        database_path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        handle = os.fdopen(os.open(lock_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600), "ab")
    except OSError as err:  # FileExistsError, NotADirectoryError, PermissionError, ...
        raise InputError(str(database_path.parent), f"cannot hold the state: {err.strerror}") from None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.close()
        raise InputError(str(database_path.parent), "another daemon is using this state directory") from None
    return handle


class Daemon:
    """The running service.  :meth:`start`, then :meth:`wait`; :meth:`shutdown` from anywhere."""

    def __init__(self, links: Links, setup: DaemonSetup) -> None:
        self.links = links
        self.setup = setup
        self._stopping = threading.Event()
        self._stopped = threading.Event()
        self._lock = threading.Lock()
        self._submitting = threading.Lock()  # one submission at a time (never taken by the tick)
        self._queue: collections.deque[Job] = collections.deque()
        self._stops = 0  # stop requests so far: a job taken before one is not handed to the loop
        self._clients = 0
        self._camera_moves: threading.Event | None = None  # a camera calibration runs; set: stop it
        self._camera_moves_ended = threading.Event()  # clear while a camera calibration runs
        self._camera_moves_ended.set()
        self._camera_progress: str | None = None  # what its moves are doing now
        self._state_lock = lock_state(setup.database_path)
        with contextlib.ExitStack() as undo:  # on failure: release what was opened
            undo.callback(self._state_lock.close)
            # bound before the hardware is touched: a second daemon on this socket is refused
            # without grounding the first one's axes mid-move
            self._server = SocketServer(setup.socket_path, self.handle, self._stopping, serving=False)
            undo.callback(self._server.close)
            self.store = Store(setup.database_path)
            undo.callback(self.store.close)
            self.records = MoveRecords(self.store, setup.calibration_key, setup.pose_navigator is not None)
            self.interrupted_moves = self.store.interrupt_running_moves()
            known = self.store.position()
            self._last_known_position_m = None if known is None else known.position_m
            if self.interrupted_moves:  # said at the start, not only in status
                log.warning(
                    "move(s) %s were interrupted by the daemon's end (a crash or kill): recorded "
                    "'interrupted', their steps as commanded",
                    ", ".join(map(str, self.interrupted_moves)),
                )
            # a bad stored camera calibration is refused before the hardware is touched
            self.camera_calibration = LocatedCalibration(links.configured_calibration, self.store)
            amplifiers = per_axis(links.open_amplifier())
            respawns_when_opened = getattr(links, "respawns", 0)  # opening the sensor may respawn
            undo.callback(release_amplifiers, amplifiers)
            for amplifier in amplifiers.values():
                amplifier.ground()
            try:
                sensor = links.open_sensor(self.camera_calibration.calibration)
            except InputError as err:
                if self.camera_calibration.calibration is None:
                    raise
                raise InputError(  # the cause is in the state, not in the configuration
                    STORED,
                    f"{err} (stored by `feeder vision calibrate[-moves] --save-state`: calibrate again, "
                    "or narrow the travel in [control])",
                ) from None
            navigator = None
            if setup.pose_navigator is not None:
                navigator = setup.pose_navigator(self.records.restored_pose_response())
            self.loop = ControlLoop(
                amplifiers,
                sensor,
                setup.modes,
                setup.loop,
                estimates=self.records.restored_estimates(),
                axis_modes=setup.axis_modes,
                navigator=navigator,
                on_position=self._save_position,
                sensor_timeout_s=setup.sensor_timeout_s,
            )
            self.link_recovery = LinkRecovery(
                links,
                self.loop,
                self.camera_calibration,
                respawns_when_opened=respawns_when_opened,
                sensor_timeout_s=setup.sensor_timeout_s,
                lock=self._lock,
                stopping=self._stopping,
                take_queue=self._take_queue,
                refuse=self._refuse_queued,
            )
            self.loop.on_fault = self.link_recovery.link_lost
            self.loop.cause_of_loss = self.link_recovery.simulator_died
            undo.pop_all()

    # -- life cycle --------------------------------------------------------
    def start(self) -> None:
        self.loop.start()
        self._server.serve()
        threading.Thread(target=self._dispatch_queue, name="queue", daemon=True).start()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Block until the shutdown is complete (output grounded, socket gone); False on
        timeout."""
        return self._stopped.wait(timeout_s)

    def shutdown(self) -> None:
        """Stop the move, ground the output, close links, remove the socket.  A second call
        (from another thread) returns when the first one is done."""
        with self._lock:
            first = not self._stopping.is_set()
            self._stopping.set()
            if self._camera_moves is not None:
                self._camera_moves.set()
        if not first:
            self._stopped.wait()
            return
        try:
            self._shut_down()
        finally:
            self._stopped.set()

    def _shut_down(self) -> None:
        with self._lock:
            queued = self._take_queue()
        for job in queued:
            self._refuse_queued(job, "daemon shutting down")
        self._wait_for_camera_moves()
        self.loop.shutdown()
        for amplifier in self.loop.amplifiers.values():
            with contextlib.suppress(FeederError, OSError):  # a dead link must not stop the shutdown
                amplifier.ground()
        with contextlib.suppress(FeederError, OSError):
            release_amplifiers(self.loop.amplifiers)
        self._server.close()
        self.store.close()
        self._state_lock.close()

    def _wait_for_camera_moves(self) -> None:
        """Let a camera calibration the shutdown stopped end (grounding its axes, storing what it
        finished) before its amplifiers, camera and store are closed; at most
        :data:`CAMERA_MOVES_END_S`."""
        if self._camera_moves_ended.is_set():
            return
        log.info("shutdown: waiting up to %g s for the camera calibration's moves to end", CAMERA_MOVES_END_S)
        if not self._camera_moves_ended.wait(CAMERA_MOVES_END_S):
            log.warning(
                "shutdown: the camera calibration did not end within %g s of its stop; closing its "
                "amplifiers, camera and store under it",
                CAMERA_MOVES_END_S,
            )

    # -- jobs ----------------------------------------------------------------
    def _save_position(self, position_m: float, poses: Reading) -> None:
        """The loop's ``on_position`` (on its record writer's thread): stored, then kept for
        ``status``, which reads no store: a write in flight holds the store (on a database another
        program has locked, for SQLite's busy timeout), and ``status`` is a waiting move's
        heartbeat (:mod:`~feeder.daemon.client`)."""
        self.store.save_position(position_m, poses)
        self._last_known_position_m = position_m

    def _take_queue(self) -> list[Job]:
        """Empty the queue (holding ``_lock``): the jobs that were in it, to refuse."""
        queued, self._queue = list(self._queue), collections.deque()
        return queued

    def _refuse_queued(self, job: Job, reason: str) -> None:
        log.warning("a queued %s was refused when its turn came: %s", job.kind, reason)
        job.result = JobResult(job.kind, "refused", reason, job.target_m, None, None, 0, 0, 0.0, {})
        job.done.set()

    def _dispatch_queue(self) -> None:
        while not self._stopping.wait(0.02):
            with self._submitting:
                with self._lock:
                    if not self._queue or self.loop.busy():
                        continue
                    job, stops = self._queue.popleft(), self._stops
                try:
                    reason = self._submit(job, stops)
                except Exception as err:
                    # the queue thread's one boundary: a move it cannot hand over (the store or
                    # the camera failing in an unforeseen way) is refused with the reason, and
                    # the thread, with the moves queued behind, goes on (it had died: the move
                    # never answered, the queue never served again)
                    log.exception("a queued move could not be handed to the loop")
                    reason = f"{type(err).__name__}: {err}"
            if reason is not None:
                self._refuse_queued(job, reason)

    def _submit(self, job: Job, stops: int) -> str | None:
        """Hand ``job`` to the loop (holding ``_submitting``); the reason it is refused, or None.

        ``stops``: :attr:`_stops` when the job was taken.  The camera's recalibration and the
        calibration's read take a while, and a stop meanwhile found no job to stop: the job is
        handed over under ``_lock``, after checking that no stop (nor the shutdown) came since."""
        if not self.loop.busy() and self.camera_calibration.saved():
            reason = self._recalibrate()
            if reason is not None:
                return reason
        reason = self._uncalibrated()
        if reason is not None:
            return reason
        with self._lock:
            if self._stopping.is_set():
                return "daemon shutting down"
            if self._stops != stops:
                return "stop requested"
            return self.loop.submit(job)

    def _uncalibrated(self) -> str | None:
        """Why every move is refused until a camera calibration that measured the image's turn
        and mirroring (``--x-move``/``--y-move``) is stored, or None."""
        reason = self.setup.uncalibrated_camera
        record = self.camera_calibration.record if self.camera_calibration.calibration is not None else None
        if reason is None or (record is not None and "moves_residual_px" in record):
            return None
        if record is None:
            return reason
        return (
            "the stored camera calibration measured no plate moves (no --x-move/--y-move): the "
            "image's turn and mirroring are unknown; calibrate with them, or set [camera] aligned = true"
        )

    def _recalibrate(self) -> str | None:
        """Locate parts with the newly stored calibration from the next move on: the camera is
        opened again with it, and the move waits for its first poses (None) or is refused."""
        try:
            record, calibration = self.camera_calibration.read()
            sensor = self.links.open_sensor(calibration)
        except (FeederError, OSError) as err:
            log.error("the stored camera calibration cannot be used: %s", err)
            return f"the stored camera calibration cannot be used: {err}"
        self.loop.replace_sensor(sensor)
        self.camera_calibration.use(record, calibration)
        log.info("locating parts with the camera calibration stored now: %s", calibration)
        deadline = time.monotonic() + self.setup.sensor_timeout_s
        while self.loop.reading is None and time.monotonic() < deadline and not self._stopping.wait(0.02):
            pass
        return None

    # -- requests ------------------------------------------------------------
    @property
    def quiet(self) -> QuietWindow:
        """Where request threads stand back for the tick (:mod:`~feeder.daemon.quiet_window`)."""
        return self.loop.quiet

    def handle(self, request: Any, hung_up: Callable[[], bool] = lambda: False) -> dict[str, Any]:
        """Answer one request object (:func:`~feeder.daemon.requests.answer`; ``hung_up``: whether
        the client has gone); waits first while the tick is due (:meth:`QuietWindow.hold`)."""
        self.quiet.hold()
        return answer(self, request, hung_up)

    def run(self, job: Job, *, queue: bool) -> tuple[int, str | None]:
        """Hand ``job`` to the loop, or (``queue``) queue it behind the running and queued moves:
        its place in the queue (0: handed to the loop) and the reason it is refused, or None."""
        with self._submitting:
            with self._lock:
                position, reason, stops = 0, None, self._stops
                if self._stopping.is_set():
                    reason = "daemon shutting down"
                elif self._camera_moves is not None:
                    reason = "a camera calibration is moving the plate: wait for it, or stop it (feeder stop)"
                elif queue and (self.loop.busy() or self._queue):
                    self._queue.append(job)
                    position = len(self._queue)
                elif self._queue:
                    reason = 'moves are queued: join the queue (feeder move --queue; "queue": true)'
            if position == 0 and reason is None:
                reason = self._submit(job, stops)
        return position, reason

    def stop(self) -> tuple[bool, int]:
        """Refuse the queued moves and stop the running one, or the camera calibration's plate
        moves: whether one was running, and how many were dequeued."""
        with self._lock:
            self._stops += 1  # a job being handed over meanwhile is refused (_submit)
            queued = self._take_queue()
            camera_moves = self._camera_moves
            if camera_moves is not None:
                camera_moves.set()
        for job in queued:
            self._refuse_queued(job, "stop requested")
        return self.loop.request_stop() or camera_moves is not None, len(queued)

    def camera_moves(
        self, moves: OffsetMoves, save: bool, hung_up: Callable[[], bool] = lambda: False
    ) -> dict[str, Any]:
        """Calibrate the camera from plate moves (:mod:`~feeder.daemon.camera_moves`) while no
        move runs, with the daemon's amplifier and camera; with ``save`` store it (unless the
        parts slipped), to locate parts with from the next move.  The report of
        :func:`~feeder.vision.offset_moves.measure` (``saved``: whether it was stored);
        :class:`~feeder.errors.FeederError` with the reason it was refused or failed.  The
        moves stop, as on :meth:`stop`, once ``hung_up()``: the client that asked has gone
        (:func:`~feeder.daemon.camera_moves.stop_on_hang_up`), and on :meth:`shutdown`, which
        waits for them to end."""
        with self._submitting, self._lock:
            if self._camera_moves is not None:
                raise FeederError("a camera calibration is running already")
            if self.loop.busy() or self._queue:
                raise FeederError("a move is running or queued: calibrate the camera once it has ended")
            if self.link_recovery.reconnecting or self._stopping.is_set():
                raise FeederError("the daemon is reconnecting a link or shutting down")
            stop = self._camera_moves = threading.Event()
            self._camera_moves_ended.clear()
        try:
            return self._calibrate_camera(moves, save, hung_up, stop)
        finally:
            self._camera_moves_ended.set()

    def _calibrate_camera(
        self, moves: OffsetMoves, save: bool, hung_up: Callable[[], bool], stop: threading.Event
    ) -> dict[str, Any]:
        """:meth:`camera_moves` once it is the one running (``stop``: set to stop its moves)."""
        try:
            configured = self.links.configured_calibration()
            assert configured is not None  # the requests check that the plane has a camera
            located = self.camera_calibration.calibration or configured
            with stop_on_hang_up(hung_up, stop), self.loop.lent_output() as amplifiers:
                log.info("camera calibration: the plate moves by offsets of %g V", moves.volts)
                report = measure(amplifiers, LoopPoses(self.loop), located, moves, self._camera_step, stop)
        except MovesStopped as err:
            log.warning("camera calibration: %s; nothing stored", err)
            raise
        except FeederError as err:
            log.error("camera calibration failed (the axes grounded where the link allowed): %s", err)
            if isinstance(err, AmplifierLinkLost):
                self.loop.amplifier_lost(str(err))
            raise
        finally:
            with self._lock:
                self._camera_moves = self._camera_progress = None
        plate = self.setup.plate_moves
        report["travel_outside"] = None if plate is None else plate.travel_outside(located.updated(report))
        report["saved"] = save and not report["slipped"] and report["travel_outside"] is None
        log.info("camera calibration: %s", summary(report))
        if report["saved"]:
            self.store.save_camera_calibration({k: v for k, v in report.items() if v is not None})
        return report

    def _camera_step(self, message: str) -> None:
        """A camera calibration's progress: logged, and shown in ``status``."""
        log.info("camera calibration: %s", message)
        with self._lock:
            self._camera_progress = message

    def status(self) -> dict[str, Any]:
        """The ``status`` reply: the loop's (:func:`.loop_status`), the faults and reconnects,
        the queue, the store, the camera's calibration and the links."""
        loop = self.loop
        with self._lock:
            faults = [dict(f) for f in self.link_recovery.faults]
            queued = len(self._queue)
            reconnecting = sorted(self.link_recovery.reconnecting)
            camera_moves, camera_progress = self._camera_moves is not None, self._camera_progress
        return {
            **loop_status(loop, self.setup.parts),
            "last_known_position_m": self._last_known_position_m,
            "reconnecting": reconnecting,
            "faults": faults,
            "queued_moves": queued,
            "camera_calibration": self.camera_calibration.status(),
            "moves_refused": self._uncalibrated() or loop.policy.store_unwritable,
            "camera_moves": camera_moves,  # a camera calibration moves the plate
            "camera_moves_progress": camera_progress,  # its axis and ramp now, or None
            "interrupted_moves": self.interrupted_moves,
            **waveforms_status(self.setup.modes),
            **self.setup.info,
            **self._live_links(),
        }

    def latest_image(self) -> Any:
        """The newest camera frame the sensor located parts in (an image array), or None."""
        latest = getattr(self.loop.sensor, "latest_image", None)
        frame = latest() if callable(latest) else None
        return None if frame is None else frame.image

    def _live_links(self) -> dict[str, Any]:
        """What may change while running (a respawned simulator's pid and endpoints)."""
        describe = getattr(self.links, "describe", None)
        return describe() if callable(describe) else {}
