"""Every socket command refuses a field it does not know and a flag that is not true or false,
before anything starts (feeder/daemon/requests.py): a misspelt ``wait`` ran a waiting move, and
on the plane a misspelt ``part`` moved part 1.  The Python client, the CLI's calls and the HTTP
console send only known fields."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

import pytest
from test_daemon_service import start

from feeder.daemon.client import Client
from feeder.daemon.request_fields import brief
from feeder.daemon.requests import COMMANDS, FIELDS, answer
from feeder.errors import DaemonRefused
from feeder.web import requests as web_requests

pytestmark = pytest.mark.timeout(60)


class _Daemon:
    """What the request handler sees of a daemon, recording every action it is asked for."""

    def __init__(self, plane: bool) -> None:
        self.actions: list[str] = []
        self.setup = type("Setup", (), {"pose_navigator": object() if plane else None, "plate_moves": None})()
        self.store = type("Store", (), {"moves": lambda _, limit: self._act("history", [])})()
        self.loop = type("Loop", (), {"release": lambda _, part: self._act("release", [])})()

    def _act(self, action: str, result: Any) -> Any:
        self.actions.append(action)
        return result

    def run(self, job: Any, *, queue: bool) -> tuple[int, str | None]:
        self.actions.append(f"run {job.kind} part {job.part} queue={queue}")
        return 0, None

    def stop(self) -> tuple[bool, int]:
        return self._act("stop", (False, 0))

    def status(self) -> dict[str, Any]:
        return self._act("status", {})

    def shutdown(self) -> None:
        self.actions.append("shutdown")


@pytest.mark.parametrize(
    ("request_", "error"),
    [
        (
            {"cmd": "move", "target_m": 2e-5, "wiat": False, "qeue": True},
            "unknown field 'wiat'; known: angle_rad, by_m, cmd, part, queue, target_m, trace, wait, "
            "x_m, y_m; did you mean 'wait'?",
        ),
        ({"cmd": "move", "x_m": 1e-4, "prat": 2}, "unknown field 'prat'; known: "),
        ({"cmd": "move", "target_m": 2e-5, "speed": 3}, "unknown field 'speed'; known: "),
        ({"cmd": "calibrate", "step": 40}, "unknown field 'step'; known: cmd, queue, steps, trace, wait"),
        ({"cmd": "status", "verbose": True}, "unknown field 'verbose'; known: cmd"),
        ({"cmd": "history", "limt": 5}, "unknown field 'limt'; known: cmd, limit; did you mean 'limit'?"),
        ({"cmd": "release", "parts": [2]}, "unknown field 'parts'; known: cmd, part; did you mean 'part'?"),
        ({"cmd": "shutdown", "force": True}, "unknown field 'force'; known: cmd"),
        ({"cmd": "calibrate_camera", "volt": 40}, "unknown field 'volt'; known: cmd, frames, "),
    ],
)
@pytest.mark.parametrize("plane", [False, True], ids=["line", "plane"])
def test_an_unknown_field_is_refused_naming_it_and_nothing_is_done(
    request_: dict[str, Any], error: str, plane: bool
) -> None:
    daemon = _Daemon(plane)
    reply = answer(daemon, request_)  # type: ignore[arg-type]
    assert reply["ok"] is False and reply["error"].startswith(error), reply
    assert daemon.actions == []


def test_a_stop_with_an_unknown_field_stops_all_the_same(caplog: pytest.LogCaptureFixture) -> None:
    """Nothing may keep a stop from the daemon: its unknown fields are logged, not refused."""
    daemon = _Daemon(plane=False)
    reply = answer(daemon, {"cmd": "stop", "now": True})  # type: ignore[arg-type]
    assert reply["ok"] is True and daemon.actions == ["stop"]
    assert "unknown field 'now'" in caplog.text and "stopped all the same" in caplog.text


def test_a_misspelt_part_on_the_plane_moves_no_part() -> None:
    """``prat`` left ``part`` at its default: part 1 moved instead of part 2."""
    daemon = _Daemon(plane=True)
    reply = answer(daemon, {"cmd": "move", "x_m": 1e-4, "prat": 2, "wait": False})  # type: ignore[arg-type]
    assert reply["error"].endswith("did you mean 'part'?") and daemon.actions == []
    reply = answer(daemon, {"cmd": "move", "x_m": 1e-4, "part": 2, "wait": False})  # type: ignore[arg-type]
    assert reply == {"ok": True, "accepted": True, "queue_position": 0}
    assert daemon.actions == ["run move part 2 queue=False"]


@pytest.mark.parametrize("key", ["wait", "queue", "trace"])
@pytest.mark.parametrize("value", ["false", "true", 0, 1, None, [], {}])
@pytest.mark.parametrize("cmd", ["move", "calibrate"])
def test_a_flag_that_is_not_a_boolean_is_refused_and_nothing_starts(key: str, value: Any, cmd: str) -> None:
    """``"wait": "false"`` (a string) ran a waiting move; ``"queue": 1`` was taken as false."""
    daemon = _Daemon(plane=False)
    fields = {"target_m": 2e-5} if cmd == "move" else {"steps": 4}
    reply = answer(daemon, {"cmd": cmd, **fields, key: value})  # type: ignore[arg-type]
    assert reply == {"ok": False, "error": f"{key} must be true or false, got {brief(value)}"}
    assert daemon.actions == []


def test_known_flags_still_steer_the_move() -> None:
    daemon = _Daemon(plane=False)
    request = {"cmd": "move", "by_m": 1e-5, "queue": True, "wait": False, "trace": False}
    assert answer(daemon, request)["accepted"] is True  # type: ignore[arg-type]
    assert daemon.actions == ["run move part 1 queue=True"]


def test_every_command_has_its_fields() -> None:
    assert set(FIELDS) == set(COMMANDS)
    assert all("cmd" in known for known in FIELDS.values())


def test_the_http_console_sends_only_fields_the_daemon_knows() -> None:
    """The console's bodies (checked against its own lists) and its jogs go to the daemon's
    request handler as they are, with ``cmd`` added."""
    for cmd in ("move", "calibrate", "calibrate_camera", "release"):  # a stop's body is not read
        assert web_requests.FIELDS[cmd] | {"cmd"} <= FIELDS[cmd], cmd
    one_axis = {"axes": {"x": {}}, "estimates": {"coarse/forward": {"step_m": 1e-6}}, "tolerance_m": 1e-7}
    plane = {
        "axes": {"x": {"step_m": 1e-6}, "y": {"step_m": 1e-6}, "theta": {}},
        "parts": [{"id": 2, "pose": [0.0, 0.0, 0.0], "step_rad": 1e-3}],
        "tolerance_m": 1e-7,
        "tolerance_rad": 1e-4,
    }
    jogs = [web_requests.jog_request(one_axis, "x", 3, 1)]
    jogs += [web_requests.jog_request(plane, axis, 3, 2) for axis in ("x", "y", "theta")]
    for jog in jogs:
        assert set(jog) <= FIELDS["move"], jog


def test_over_the_socket_a_misspelt_request_is_refused_and_nothing_recorded(short_dir: Path) -> None:
    """The audit's requests, on the daemon with the fake world: refused, no move recorded."""
    daemon, _ = start(short_dir)
    try:
        with Client(short_dir / "run" / "f.sock") as client:
            reply = client.request("move", target_m=2e-5, wiat=False, qeue=True)
            assert reply["ok"] is False and reply["error"].endswith("did you mean 'wait'?"), reply
            reply = client.request("move", target_m=2e-5, wait="false")
            assert reply == {"ok": False, "error": "wait must be true or false, got 'false'"}
            assert client.request("history")["moves"] == []
            assert client.request("status")["state"] == "idle"
    finally:
        daemon.shutdown()


def test_the_client_sends_only_fields_the_daemon_knows(short_dir: Path) -> None:
    """Every typed call of :class:`Client` (the CLI's commands make these) passes the daemon's
    field check: any refusal it meets is the daemon's judgement of the job, not of a field."""
    daemon, _ = start(short_dir)
    refusals: list[str] = []
    try:
        with Client(short_dir / "run" / "f.sock", timeout_s=20.0) as client:
            calls = [
                lambda: client.status(),
                lambda: client.history(5),
                lambda: client.move_to(1e-5),
                lambda: client.move_by(-5e-6, queue=True),
                lambda: client.move_to_pose(x_m=2e-5, part=1, wait=False),
                lambda: client.stop(),
                lambda: client.calibrate(4, wait=False),
                lambda: client.stop(),
                lambda: client.release(),
                lambda: client.release(1),
                lambda: client.calibrate_camera(volts=10.0, frames=2, save=False),
                lambda: client.shutdown(),
            ]
            for call in calls:
                try:
                    call()
                except DaemonRefused as err:
                    refusals.append(err.reason)
    finally:
        with contextlib.suppress(DaemonRefused):
            daemon.shutdown()
    assert refusals, "calibrate_camera is refused on one axis (after its fields were checked)"
    for reason in refusals:
        assert "unknown field" not in reason and "true or false" not in reason, reason
