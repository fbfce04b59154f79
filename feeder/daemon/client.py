"""Client of the daemon's Unix socket: one JSON object per line each way.

Requests are ``{"cmd": "move" | "stop" | "status" | "calibrate" | "calibrate_camera" |
"history" | "release" | "shutdown", ...}``; replies are ``{"ok": true, ...}`` or ``{"ok":
false, "error": "..."}``.  The client refuses a socket that another user owns, so a
planted socket cannot impersonate the daemon (the wire: :mod:`feeder.daemon.client_connection`).

:class:`Client` (also ``feeder.Client``) has two layers:

- typed calls for scripts: :meth:`~Client.move_to`, :meth:`~Client.move_by`,
  :meth:`~Client.calibrate`, :meth:`~Client.stop`, :meth:`~Client.status`,
  :meth:`~Client.history`, :meth:`~Client.release`, :meth:`~Client.shutdown`,
  :meth:`~Client.calibrate_camera`.  They return dataclasses (the camera's report a dict)
  (:mod:`feeder.daemon.replies`: SI units, the protocol's key names) and raise
  the :class:`~feeder.errors.DaemonError` family: :class:`~feeder.errors.DaemonRefused`,
  :class:`~feeder.errors.MoveFailed` (:class:`~feeder.errors.MoveFaulted`),
  :class:`~feeder.errors.DaemonUnreachable` (:class:`~feeder.errors.DaemonTimeout`).
- :meth:`Client.request`: one raw request, the reply object as it came.

Timeouts.  ``timeout_s`` bounds every reply or acknowledgement, never a move's
duration.  The daemon answers a waiting move only when it ends, so while waiting
the client sends a heartbeat (a ``status`` request on a second connection) after
every :data:`HEARTBEAT_S` of silence; a heartbeat unanswered within ``timeout_s``
raises :class:`~feeder.errors.DaemonTimeout`.  A stopped (SIGSTOP) or hung daemon
is thus reported within ``timeout_s + HEARTBEAT_S``, a dead one at once (its
connection closes); the move itself may run for as long as it takes.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal, TypeVar, overload

from feeder.daemon.client_connection import Connection, default_socket_path, listening
from feeder.daemon.replies import Accepted, MoveRecord, MoveResult, Status, StopResult
from feeder.errors import (
    DaemonRefused,
    DaemonTimeout,
    DaemonUnreachable,
    InputError,
    MoveFailed,
    MoveFaulted,
)

DEFAULT_TIMEOUT_S = 10.0
HEARTBEAT_S = 0.25
"""Silence on a waiting move after which the client checks that the daemon still answers."""
SHUTDOWN_POLL_S = 0.02

T = TypeVar("T")

DaemonUnavailable = DaemonUnreachable
"""The former name of :class:`~feeder.errors.DaemonUnreachable`."""


# -- the client ---------------------------------------------------------------


class Client:
    """The daemon at ``socket_path`` (default :func:`default_socket_path`).

    Connects at once (:class:`~feeder.errors.DaemonUnreachable` when nobody listens)
    and keeps the connection; one that failed or timed out is replaced on the next
    call.  ``timeout_s`` is the default of every typed call's ``timeout_s``.  Not
    thread-safe: one client per thread.
    """

    def __init__(self, socket_path: Path | str | None = None, timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise InputError("timeout_s", f"must be a positive number of seconds, got {timeout_s!r}")
        self.socket_path = default_socket_path() if socket_path is None else Path(socket_path)
        self.timeout_s = timeout_s
        self._conn: Connection | None = Connection(self.socket_path, timeout_s)

    # -- raw requests -----------------------------------------------------------
    def request(self, cmd: str, timeout_s: float | None = None, **fields: Any) -> dict[str, Any]:
        """Send one request and return the reply object (``ok`` tells success).

        ``timeout_s`` bounds the reply (None: wait as long as it takes, e.g. for a
        waiting move without heartbeat).
        """
        conn = self._connection()
        try:
            conn.send(cmd, fields, timeout_s)
            return conn.receive(cmd, timeout_s)
        except DaemonUnreachable:
            self._drop()  # a late reply would answer the next request
            raise

    def _connection(self) -> Connection:
        if self._conn is None:
            self._conn = Connection(self.socket_path, self.timeout_s)
        return self._conn

    def _drop(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def close(self) -> None:
        self._drop()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- typed calls -----------------------------------------------------------
    def _timeout(self, timeout_s: float | None) -> float:
        if timeout_s is None:
            return self.timeout_s
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise InputError("timeout_s", f"must be a positive number of seconds, got {timeout_s!r}")
        return timeout_s

    def _call(self, cmd: str, timeout_s: float | None, **fields: Any) -> dict[str, Any]:
        reply = self.request(cmd, self._timeout(timeout_s), **fields)
        if reply.get("ok") is not True:
            raise DaemonRefused(str(reply.get("error") or f"{cmd} refused without a reason"))
        return reply

    def status(self, *, timeout_s: float | None = None) -> Status:
        """The daemon's state, position and learned steps."""
        reply = self._call("status", timeout_s)
        return _parse("status", Status.from_dict, reply)

    def history(self, limit: int = 100, *, timeout_s: float | None = None) -> list[MoveRecord]:
        """The newest ``limit`` recorded moves, oldest first."""
        reply = self._call("history", timeout_s, limit=limit)
        return _parse("history", lambda r: [MoveRecord.from_dict(m) for m in r["moves"]], reply)

    def release(self, part: int | None = None, *, timeout_s: float | None = None) -> list[int]:
        """Let held parts go (``part``, or every part): later moves of other parts no longer keep
        them at their targets.  The ids released; :class:`DaemonRefused` while a
        move runs."""
        if part is not None and (isinstance(part, bool) or not isinstance(part, int) or part < 1):
            raise InputError("part", f"must be a part id ≥ 1, got {part!r}")
        reply = self._call("release", timeout_s, **({} if part is None else {"part": part}))
        return _parse("release", lambda r: [int(p) for p in r["released"]], reply)

    def stop(self, *, timeout_s: float | None = None) -> StopResult:
        """Stop the running move and drop queued ones (the move's own call then raises
        :class:`~feeder.errors.MoveFailed` with status ``stopped``)."""
        reply = self._call("stop", timeout_s)
        return _parse("stop", lambda r: StopResult(bool(r["stopped"]), int(r["dequeued"])), reply)

    def shutdown(self, *, wait: bool = True, timeout_s: float | None = None) -> None:
        """Stop the daemon (it stops the move, grounds the output and closes its links).

        With ``wait``, return once nothing listens on the socket any more (removed, or
        refusing connections); :class:`~feeder.errors.DaemonTimeout` when it still does
        after ``timeout_s``.
        """
        timeout = self._timeout(timeout_s)
        self._connection()  # nobody listening: DaemonUnreachable
        try:
            self._call("shutdown", timeout)
        except DaemonTimeout:
            raise
        except DaemonUnreachable:
            pass  # it went away before its acknowledgement got out; checked below
        self._drop()
        end = time.monotonic() + timeout
        while wait and listening(self.socket_path, SHUTDOWN_POLL_S):
            if time.monotonic() > end:
                raise DaemonTimeout(
                    f"the daemon acknowledged the shutdown but still listens on "
                    f"{self.socket_path} after {timeout:g} s",
                    timeout,
                )
            time.sleep(SHUTDOWN_POLL_S)

    @overload
    def move_to(
        self, target_m: float, *, queue: bool = ..., wait: Literal[True] = ..., timeout_s: float | None = ...
    ) -> MoveResult: ...

    @overload
    def move_to(
        self, target_m: float, *, queue: bool = ..., wait: Literal[False], timeout_s: float | None = ...
    ) -> Accepted: ...

    @overload
    def move_to(
        self, target_m: float, *, queue: bool = ..., wait: bool = ..., timeout_s: float | None = ...
    ) -> MoveResult | Accepted: ...

    def move_to(
        self, target_m: float, *, queue: bool = False, wait: bool = True, timeout_s: float | None = None
    ) -> MoveResult | Accepted:
        """Move the part to ``target_m`` (m).

        queue: wait behind a running move instead of being refused.  wait: return the
        result when the move ends (a :class:`MoveResult` with status ``done``; any other
        end raises :class:`~feeder.errors.MoveFailed`), else :class:`Accepted` once the
        daemon took it.
        """
        return self._job("move", {"target_m": _metres("target_m", target_m)}, queue, wait, timeout_s)

    @overload
    def move_by(
        self, delta_m: float, *, queue: bool = ..., wait: Literal[True] = ..., timeout_s: float | None = ...
    ) -> MoveResult: ...

    @overload
    def move_by(
        self, delta_m: float, *, queue: bool = ..., wait: Literal[False], timeout_s: float | None = ...
    ) -> Accepted: ...

    @overload
    def move_by(
        self, delta_m: float, *, queue: bool = ..., wait: bool = ..., timeout_s: float | None = ...
    ) -> MoveResult | Accepted: ...

    def move_by(
        self, delta_m: float, *, queue: bool = False, wait: bool = True, timeout_s: float | None = None
    ) -> MoveResult | Accepted:
        """Move the part by ``delta_m`` (m) from where it is when the move starts; as
        :meth:`move_to`."""
        return self._job("move", {"by_m": _metres("delta_m", delta_m)}, queue, wait, timeout_s)

    @overload
    def move_to_pose(
        self,
        x_m: float | None = ...,
        y_m: float | None = ...,
        angle_rad: float | None = ...,
        *,
        part: int = ...,
        queue: bool = ...,
        wait: Literal[True] = ...,
        timeout_s: float | None = ...,
    ) -> MoveResult: ...

    @overload
    def move_to_pose(
        self,
        x_m: float | None = ...,
        y_m: float | None = ...,
        angle_rad: float | None = ...,
        *,
        part: int = ...,
        queue: bool = ...,
        wait: Literal[False],
        timeout_s: float | None = ...,
    ) -> Accepted: ...

    @overload
    def move_to_pose(
        self,
        x_m: float | None = ...,
        y_m: float | None = ...,
        angle_rad: float | None = ...,
        *,
        part: int = ...,
        queue: bool = ...,
        wait: bool = ...,
        timeout_s: float | None = ...,
    ) -> MoveResult | Accepted: ...

    def move_to_pose(
        self,
        x_m: float | None = None,
        y_m: float | None = None,
        angle_rad: float | None = None,
        *,
        part: int = 1,
        queue: bool = False,
        wait: bool = True,
        timeout_s: float | None = None,
    ) -> MoveResult | Accepted:
        """Bring ``part`` to a pose in the plate frame: any of ``x_m``, ``y_m`` (m, centre) and
        ``angle_rad`` (its first dimension's direction from +x towards +y); what is not given
        keeps its value.  Waits for the end, or returns once accepted, as :meth:`move_to`."""
        target = {
            key: _finite(key, value, unit)
            for key, value, unit in (
                ("x_m", x_m, "metres"),
                ("y_m", y_m, "metres"),
                ("angle_rad", angle_rad, "radians"),
            )
            if value is not None
        }
        if not target:
            raise InputError("pose", "give at least one of x_m, y_m and angle_rad")
        if isinstance(part, bool) or not isinstance(part, int) or part < 1:
            raise InputError("part", f"must be a part id (an integer >= 1), got {part!r}")
        return self._job("move", {**target, "part": part}, queue, wait, timeout_s)

    @overload
    def calibrate(
        self, steps: int = ..., *, queue: bool = ..., wait: Literal[True] = ..., timeout_s: float | None = ...
    ) -> MoveResult: ...

    @overload
    def calibrate(
        self, steps: int = ..., *, queue: bool = ..., wait: Literal[False], timeout_s: float | None = ...
    ) -> Accepted: ...

    @overload
    def calibrate(
        self, steps: int = ..., *, queue: bool = ..., wait: bool = ..., timeout_s: float | None = ...
    ) -> MoveResult | Accepted: ...

    def calibrate(
        self, steps: int = 20, *, queue: bool = False, wait: bool = True, timeout_s: float | None = None
    ) -> MoveResult | Accepted:
        """Learn the step sizes: ``steps`` coarse steps per direction (2–10000), both
        waveforms, forward and back; as :meth:`move_to`."""
        if isinstance(steps, bool) or not isinstance(steps, int) or not 2 <= steps <= 10_000:
            raise InputError("steps", f"must be an integer in [2, 10000], got {steps!r}")
        return self._job("calibrate", {"steps": steps}, queue, wait, timeout_s)

    def calibrate_camera(
        self,
        *,
        volts: float | None = None,
        stack_gain_m_per_v: float | None = None,
        increment_v: float | None = None,
        frames: int | None = None,
        slip_fraction: float | None = None,
        save: bool = False,
        timeout_s: float | None = None,
        progress: Callable[[str], None] | None = None,
    ) -> dict[str, Any]:
        """The camera's calibration from plate moves the daemon makes with its own amplifier and
        camera while no move runs (``feeder vision calibrate-moves --daemon``; the fields and
        report as :func:`feeder.vision.offset_moves.measure`'s, plus ``saved`` and ``image_px``;
        the daemon's defaults for what is None).  ``save`` stores it for the next move.  Returns
        when the moves end (about a minute), checking on the daemon by heartbeat, whose status
        hands ``progress`` each new step of the moves ("x: offset 0 → 100 V in 0.05 V steps");
        :class:`~feeder.errors.DaemonRefused` with the reason it was refused, stopped or failed."""
        given = {"volts": volts, "stack_gain_m_per_v": stack_gain_m_per_v, "increment_v": increment_v,
                 "slip_fraction": slip_fraction}  # fmt: skip
        fields: dict[str, Any] = {k: v for k, v in given.items() if v is not None}
        if frames is not None:
            fields["frames"] = frames
        shown: list[str] = []

        def heard(status: dict[str, Any]) -> None:
            now = status.get("camera_moves_progress")
            if progress is not None and isinstance(now, str) and now not in shown:
                shown.append(now)
                progress(now)

        reply = self._await("calibrate_camera", {**fields, "save": save}, self._timeout(timeout_s), heard)
        if reply.get("ok") is not True:
            raise DaemonRefused(str(reply.get("error") or "calibrate_camera refused without a reason"))
        return _parse("calibrate_camera", lambda r: dict(r["calibration"]), reply)

    def _job(
        self, cmd: str, fields: dict[str, Any], queue: bool, wait: bool, timeout_s: float | None
    ) -> MoveResult | Accepted:
        timeout = self._timeout(timeout_s)
        fields = {**fields, "queue": queue, "wait": wait}
        if not wait:
            reply = self._call(cmd, timeout, **fields)
            return _parse(cmd, lambda r: Accepted(int(r.get("queue_position") or 0)), reply)
        reply = self._await(cmd, fields, timeout)
        if "result" not in reply:
            raise DaemonRefused(str(reply.get("error") or f"{cmd} refused without a reason"))
        result = _parse(cmd, lambda r: MoveResult.from_dict(r["result"]), reply)
        if result.status == "done":
            return result
        if result.status == "refused":
            raise DaemonRefused(result.reason, result)
        raise (MoveFaulted if result.status == "fault" else MoveFailed)(result)

    def _await(
        self,
        cmd: str,
        fields: dict[str, Any],
        timeout_s: float,
        heard: Callable[[dict[str, Any]], None] = lambda _: None,
    ) -> dict[str, Any]:
        """Send a request the daemon answers only when the job ends; check on it by heartbeat
        (see the module's docstring), each heartbeat's status handed to ``heard``."""
        conn = self._connection()
        heartbeat: Connection | None = None
        try:
            conn.send(cmd, fields, timeout_s)
            while True:
                try:
                    return conn.receive(cmd, HEARTBEAT_S)
                except DaemonTimeout:
                    pass  # silence: the job runs; is the daemon still there?
                if heartbeat is None:
                    heartbeat = Connection(self.socket_path, timeout_s)
                heartbeat.send("status", {}, timeout_s)
                heard(heartbeat.receive("status (heartbeat)", timeout_s))
        except DaemonUnreachable:
            self._drop()
            raise
        finally:
            if heartbeat is not None:
                heartbeat.close()


def _metres(name: str, value: float) -> float:
    return _finite(name, value, "metres")


def _finite(name: str, value: float, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(name, f"must be a finite number of {unit}, got {value!r}")
    return float(value)


def _parse(cmd: str, parse: Callable[[dict[str, Any]], T], reply: dict[str, Any]) -> T:
    """``parse(reply)``; a reply without the protocol's fields is :class:`DaemonUnreachable`."""
    try:
        return parse(reply)
    except (KeyError, TypeError, ValueError) as err:
        raise DaemonUnreachable(
            f"malformed reply to {cmd!r} ({type(err).__name__}: {err}): {json.dumps(reply)[:200]}"
        ) from None
