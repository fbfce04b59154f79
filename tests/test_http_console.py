"""The browser console's HTTP API (feeder/web/) over real TCP, in front of the
service with the in-process fake world as hardware."""

from __future__ import annotations

import http.client
import json
import os
import resource
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("uvicorn")

from test_daemon_service import start, wait_for

from feeder.daemon.config import HttpConfig
from feeder.daemon.config_file import load_config
from feeder.daemon.service import Daemon
from feeder.daemon.tick_timing import TICK_PRIORITY
from feeder.errors import InputError
from feeder.web.security import RateLimit
from feeder.web.server import ConsoleServer, start_console

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.timeout(60)

ENDPOINTS = [
    ("GET", "/api/status"),
    ("GET", "/api/history"),
    ("POST", "/api/move"),
    ("POST", "/api/jog"),
    ("POST", "/api/stop"),
    ("POST", "/api/calibrate"),
    ("POST", "/api/calibrate_camera"),
    ("POST", "/api/release"),
    ("GET", "/api/live"),
    ("GET", "/api/unknown"),
    ("GET", "/favicon.ico"),
]


class Console:
    """A running daemon (fake world) with its console on a free loopback port."""

    def __init__(self, base: Path, **http: Any) -> None:
        self.daemon, _ = start(base)
        wait_for(lambda: self.daemon.loop.position_m is not None)
        settings = HttpConfig(port=0, **http)
        self.server: ConsoleServer = start_console(self.daemon, settings, base / "state")
        self.token = self.server.token
        self.origin = f"http://127.0.0.1:{self.server.port}"

    def call(
        self,
        method: str,
        path: str,
        body: Any = None,
        token: str | None = "",
        headers: dict[str, str] | None = None,
        raw: bytes | None = None,
    ) -> tuple[int, dict[str, Any], dict[str, str]]:
        """One request on a fresh connection: (status code, JSON reply, headers)."""
        conn = http.client.HTTPConnection("127.0.0.1", self.server.port, timeout=30)
        sent = dict(headers or {})
        if token is not None:
            sent["Authorization"] = f"Bearer {token or self.token}"
        data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
        try:
            conn.request(method, path, body=data, headers=sent)
            response = conn.getresponse()
            text = response.read()
            return response.status, json.loads(text), dict(response.getheaders())
        finally:
            conn.close()

    def stop(self) -> None:
        self.server.stop()
        self.daemon.shutdown()


@pytest.fixture
def console(short_dir: Path) -> Iterator[Console]:
    running = Console(short_dir)
    yield running
    running.stop()


def test_the_page_loads_without_the_token_and_holds_no_data(console: Console) -> None:
    conn = http.client.HTTPConnection("127.0.0.1", console.server.port, timeout=10)
    conn.request("GET", "/")
    page = conn.getresponse()
    html = page.read().decode()
    script = ""
    for name in ("plate_view.js", "console.js"):
        conn.request("GET", f"/{name}")
        answer = conn.getresponse()
        assert answer.status == 200 and answer.getheader("Content-Type", "").startswith("text/javascript")
        script += answer.read().decode()
    conn.close()
    assert page.status == 200 and page.getheader("Content-Type", "").startswith("text/html")
    assert "frame-ancestors 'none'" in page.getheader("Content-Security-Policy", "")
    assert '<script src="plate_view.js">' in html and '<script src="console.js">' in html
    assert "Authorization" in script
    assert console.token not in html + script
    assert "position_m" not in html  # the state comes from /api only


def test_the_token_file_is_owner_only_and_new_at_each_start(console: Console, short_dir: Path) -> None:
    path = short_dir / "state" / "http-token"
    assert oct(path.stat().st_mode & 0o777) == "0o600"
    assert path.read_text().strip() == console.token and len(console.token) >= 40
    assert console.server.token_url == f"{console.origin}/#token={console.token}"
    second = start_console(console.daemon, HttpConfig(port=0), short_dir / "state")
    try:
        assert second.token != console.token and path.read_text().strip() == second.token
    finally:
        second.stop()


def test_every_endpoint_without_the_token_gets_401_and_nothing_moves(console: Console) -> None:
    for method, path in ENDPOINTS:
        for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": f"Basic {console.token}"}):
            code, reply, sent_headers = console.call(method, path, {"target_m": 100e-6}, None, headers)
            assert code == 401, (method, path, headers, code)
            assert reply["ok"] is False and "token" in reply["error"]
            assert sent_headers.get("www-authenticate") == "Bearer"
    assert console.daemon.store.moves(10) == []


def test_a_cross_origin_post_gets_403_a_script_and_the_page_pass(console: Console) -> None:
    for origin in ("http://evil.example", "null", f"http://127.0.0.1:{console.server.port + 1}"):
        code, reply, _ = console.call("POST", "/api/move", {"target_m": 50e-6}, headers={"Origin": origin})
        assert code == 403 and origin in reply["error"]
    assert console.daemon.store.moves(10) == []
    code, reply, _ = console.call("POST", "/api/move", {"target_m": 50e-6})  # no Origin: a script
    assert code == 200 and reply["result"]["status"] == "done", reply
    code, reply, _ = console.call(
        "POST", "/api/move", {"target_m": 0.0}, headers={"Origin": f"http://localhost:{console.server.port}"}
    )
    assert code == 200 and abs(reply["result"]["error_m"]) <= 1e-6
    assert [m["target_m"] for m in console.daemon.store.moves(10)] == [50e-6, 0.0]


@pytest.mark.parametrize(
    ("method", "path", "raw", "code", "words"),
    [
        ("POST", "/api/move", b"{not json", 400, "malformed JSON"),
        ("POST", "/api/move", b"\xff\xfe", 400, "malformed JSON"),
        ("POST", "/api/move", b"[1, 2]", 400, "JSON object"),
        ("POST", "/api/move", b'{"target_m": NaN}', 400, "target_m must be a finite number"),
        ("POST", "/api/move", b'{"target_m": true}', 400, "target_m must be a finite number"),
        ("POST", "/api/move", b'{"angle_rad": 400}', 400, "must lie within ±2π (one turn), got 400"),
        ("POST", "/api/move", b'{"target_m": 1e-4, "speed": 3}', 400, "unknown field 'speed'"),
        ("POST", "/api/move", b'{"target_m": 1e-4, "wait": "no"}', 400, "wait must be true or false"),
        ("POST", "/api/move", b"{" + b'"a":' * 0 + b'"target_m": ' + b"[" * 100_000, 413, "longer than"),
        ("POST", "/api/move", b'{"target_m": 1e-4, "by_m": 1e-5}', 400, "exactly one of"),
        ("POST", "/api/move", b'{"x_m": 1e-4, "target_m": 1e-4}', 400, "exactly one of"),
        ("POST", "/api/move", b'{"target_m": 1.0}', 409, "travel"),
        ("POST", "/api/calibrate", b'{"steps": 1}', 409, "steps must be an integer in [2, 10000]"),
        ("POST", "/api/calibrate", b'{"steps": 2.5}', 400, "steps must be an integer"),
        ("POST", "/api/jog", b'{"steps": 3}', 400, "give axis"),
        ("POST", "/api/jog", b'{"axis": "x", "steps": 0}', 400, "non-zero"),
        ("POST", "/api/jog", b'{"axis": "y", "steps": 3}', 409, "one axis"),
        ("POST", "/api/move", b'{"x_m": 1e-4, "part": 0}', 400, "part must be a part id ≥ 1, got 0"),
        ("POST", "/api/release", b'{"part": "all"}', 400, "part must be an integer"),
        ("POST", "/api/release", b'{"parts": [1]}', 400, "unknown field 'parts' for release"),
        ("POST", "/api/calibrate_camera", b'{"volt": 40}', 400, "unknown field 'volt' for calibrate_camera"),
        ("POST", "/api/calibrate_camera", b'{"volts": "40"}', 400, "volts must be a finite number"),
        ("POST", "/api/calibrate_camera", b'{"frames": 2.5}', 400, "frames must be an integer"),
        ("POST", "/api/calibrate_camera", b'{"save": 1}', 400, "save must be true or false"),
        ("POST", "/api/calibrate_camera", b'{"volts": 40}', 409, "calibrate the camera of a plane"),
        ("GET", "/api/history?limit=abc", None, 400, "limit must be"),
        ("GET", "/api/history?limit=0", None, 409, "limit must be an integer in [1, 100000]"),
        ("GET", "/api/move", None, 405, "Method Not Allowed"),
        ("GET", "/api/nothing", None, 404, "Not Found"),
    ],
)
def test_bad_requests_get_a_json_error_with_a_4xx_code(
    console: Console, method: str, path: str, raw: bytes | None, code: int, words: str
) -> None:
    got, reply, headers = console.call(method, path, raw=raw)
    assert got == code, reply
    assert headers["content-type"] == "application/json"
    assert reply["ok"] is False and words in reply["error"], reply
    assert "Traceback" not in reply["error"]
    assert console.call("GET", "/api/status")[0] == 200  # still serving
    assert console.daemon.store.moves(10) == []


def test_moves_are_rate_limited_and_stop_never_is(short_dir: Path) -> None:
    console = Console(short_dir, moves_per_s=0.5, move_burst=3)
    try:
        codes = [console.call("POST", "/api/move", {"target_m": 300e-6, "wait": False})[0] for _ in range(3)]
        code, reply, headers = console.call("POST", "/api/jog", {"axis": "x", "steps": 5})
        stops = [console.call("POST", "/api/stop")[0] for _ in range(10)]
    finally:
        console.stop()
    assert codes == [200, 409, 409]  # accepted, then "a move is in progress"
    assert code == 429 and "too many moves" in reply["error"] and headers["retry-after"] == "1"
    assert stops == [200] * 10


@pytest.mark.parametrize("raw", [b'{"now": true}', b"{not json", b"[1]"])
def test_a_stop_acts_whatever_its_body(console: Console, raw: bytes) -> None:
    """A stop whose body the console cannot use stops all the same (it was refused, 400)."""
    code, reply, _ = console.call("POST", "/api/stop", raw=raw)
    assert code == 200 and reply["ok"] is True and reply["stopped"] is not None, reply


def test_rate_limit_refills_at_its_rate() -> None:
    now = [0.0]
    limit = RateLimit(per_s=2.0, burst=2, clock=lambda: now[0])
    assert [limit.take() for _ in range(3)] == [0.0, 0.0, pytest.approx(0.5)]
    now[0] = 0.5
    assert limit.take() == 0.0 and limit.take() == pytest.approx(0.5)


def test_one_axis_holds_no_part_and_release_lets_none_go(console: Console) -> None:
    assert console.call("GET", "/api/status")[1]["held"] == []
    assert console.call("POST", "/api/release", {})[:2] == (200, {"ok": True, "released": []})
    code, reply, _ = console.call("POST", "/api/release", {"part": 2})
    assert code == 409 and reply["error"] == "part 2 is not on the plate (the camera sees 1 part(s))"


def test_a_jog_moves_by_learned_steps(console: Console) -> None:
    start = console.call("GET", "/api/status")[1]
    step = start["estimates"]["coarse/forward"]["step_m"]
    code, reply, _ = console.call("POST", "/api/jog", {"axis": "x", "steps": 30})
    assert code == 200 and reply["accepted"] is True, reply
    assert reply["jog"]["by_m"] == pytest.approx(30 * step)

    # the move's record begins when the loop starts the job, a tick after it was accepted
    def statuses() -> list[str]:
        return [move["status"] for move in console.call("GET", "/api/history")[1]["moves"]]

    wait_for(lambda: statuses() not in ([], ["running"]))
    (move,) = console.call("GET", "/api/history?limit=5")[1]["moves"]
    assert move["status"] == "done"
    assert move["reached_m"] - start["position_m"] == pytest.approx(30 * step, abs=2e-6)


BURST = """
import concurrent.futures, http.client, json, sys, time
port, token, ROUNDS = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
def status(_):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    conn.request("GET", "/api/status", headers={"Authorization": "Bearer " + token})
    response = conn.getresponse()
    return response.status, json.loads(response.read())["state"]
with concurrent.futures.ThreadPoolExecutor(100) as pool:
    print("ready", flush=True)
    sys.stdin.readline()
    began = time.monotonic()
    replies = []
    for _ in range(ROUNDS):  # 100 at once, again and again: a measurable number of ticks
        replies += list(pool.map(status, range(100)))
print(json.dumps([replies, time.monotonic() - began]), flush=True)
"""


WITNESS = """
import json, os, select, sys, time
try:  # the tick's own scheduling where allowed
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(sys.argv[1])))
except OSError:
    pass
print("ready", flush=True)
sys.stdin.readline()
late, deadline = [], time.monotonic() + 0.01
while not select.select([sys.stdin], [], [], 0)[0]:  # until told to stop
    delay = deadline - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    late.append(time.monotonic() - deadline)
    deadline += 0.01
print(json.dumps(late), flush=True)
"""
"""The machine's own jitter: a process of its own sleeping to 10 ms deadlines, as the tick does
but with no interpreter to share, at the tick's priority where allowed."""

ROUNDS = 10
JITTER_GOAL_P99_S = 0.5e-3
"""The tick's own goal (benchmarks/loop_jitter.py), which must hold during the burst."""
ATTEMPTS = 5


def _started(script: str, *args: str) -> subprocess.Popen[str]:
    """A helper process, once it says it is ready (it then waits for a line on stdin)."""
    process = subprocess.Popen(
        [sys.executable, "-c", script, *args], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert process.stdout is not None and process.stdin is not None
    assert process.stdout.readline().strip() == "ready"
    return process


def _tell(process: subprocess.Popen[str], line: str) -> None:
    assert process.stdin is not None
    process.stdin.write(line + "\n")
    process.stdin.flush()


def _used_s(usage: resource.struct_rusage) -> float:
    return usage.ru_utime + usage.ru_stime


def _reply(process: subprocess.Popen[str]) -> tuple[Any, float]:
    """The helper's last line, and the CPU seconds it used in its life."""
    assert process.stdout is not None
    reply = json.loads(process.stdout.readline())
    before = _used_s(resource.getrusage(resource.RUSAGE_CHILDREN))
    assert process.wait(10) == 0
    return reply, _used_s(resource.getrusage(resource.RUSAGE_CHILDREN)) - before


FOREIGN_CORES = 0.25
"""Other programs' mean CPU use (cores) above which a burst's machine was not quiet: they take
the cores from the daemon's threads of ordinary priority, which then hold the interpreter the
tick waits for, while the witness at real-time priority does not notice them."""


def _cpu_s() -> tuple[float, float]:
    """(CPU seconds the whole machine spent busy, those of this process's own threads).

    The burst's helper processes are counted as each is waited for (:func:`_reply`), not by
    ``RUSAGE_CHILDREN`` over the burst: that also takes in the whole life of any earlier test's
    child reaped meanwhile (``subprocess`` reaps finished orphans whenever a process starts),
    which had read other programs' use as 0.00 cores in a loaded CI run."""
    with open("/proc/stat") as stat:
        ticks = [int(v) for v in stat.readline().split()[1:9]]
    busy = sum(ticks) - ticks[3] - ticks[4]  # all but idle and iowait
    return busy / os.sysconf("SC_CLK_TCK"), _used_s(resource.getrusage(resource.RUSAGE_SELF))


def _burst(console: Console) -> tuple[np.ndarray, np.ndarray, list[str], float, float]:
    """ROUNDS × 100 concurrent status requests during a move: the tick lateness during the
    burst and the witness' lateness over the same time (s), the states answered, the burst's
    duration (s), other programs' mean CPU use meanwhile (cores)."""
    daemon: Daemon = console.daemon
    busy_before, ours_before, began = *_cpu_s(), time.monotonic()
    # the clients in a process of their own, as browsers and scripts are
    clients = _started(BURST, str(console.server.port), console.token, str(ROUNDS))
    witness = _started(WITNESS, str(TICK_PRIORITY))
    far = -0.95e-3 if daemon.status()["position_m"] > 0 else 0.95e-3  # the travel is ±1 mm
    code, reply, _ = console.call("POST", "/api/move", {"target_m": far, "wait": False})
    assert code == 200 and reply["accepted"], reply
    wait_for(lambda: daemon.status()["state"] == "moving")
    ticks = daemon.loop.ticks
    _tell(witness, "go")
    _tell(clients, "go")
    (replies, took_s), clients_s = _reply(clients)
    during = daemon.loop.lateness.last(daemon.loop.ticks - ticks)
    _tell(witness, "stop")
    late, witness_s = _reply(witness)
    machine = np.array(late)
    busy, ours = _cpu_s()
    ours += clients_s + witness_s
    foreign = max(0.0, (busy - busy_before) - (ours - ours_before)) / (time.monotonic() - began)
    assert console.call("POST", "/api/stop")[0] == 200
    wait_for(lambda: daemon.status()["state"] == "idle", 30)
    last = daemon.status()["last_result"]
    assert [code for code, _ in replies] == [200] * 100 * ROUNDS
    assert last["status"] in ("stopped", "done") and last["steps"] > 0
    period_s = 1 / daemon.loop.settings.rate_hz
    assert during.size >= 0.5 * took_s / period_s  # the tick kept its rate
    return during, machine, [state for _, state in replies], took_s, foreign


def test_100_concurrent_status_requests_during_a_move_keep_the_tick_on_time(console: Console) -> None:
    """The console's threads stand back while the tick is due (feeder/daemon/quiet_window.py):
    the tick keeps its goal during the burst. Without that, every burst measured 1.2-3.5 ms p99
    here on a quiet machine (the console's threads held the interpreter when the tick woke).

    The shared machine is itself noisy at times (a C program sleeping to 10 ms deadlines at
    real-time priority has measured p99 3.8 ms; docs/console.md). A witness process sleeps to
    10 ms deadlines during each burst (its p99 tracks the tick's: 3.4/1.3, 2.8/1.7, 0.22/0.17,
    0.60/0.86, 0.50/0.59 ms). The goal must hold in one of up to ATTEMPTS bursts; if none keeps
    it, the daemon is at fault only if the machine was plainly quiet during some burst (the
    witness within half the goal, and other programs using under FOREIGN_CORES), else the test
    skips, saying so."""
    attempts = []
    for _ in range(ATTEMPTS):
        during, machine, states, took_s, foreign = _burst(console)
        p99_s, machine_p99_s = float(np.percentile(during, 99)), float(np.percentile(machine, 99))
        attempts.append((p99_s, machine_p99_s, foreign))
        print(
            f"\n{ROUNDS} × 100 concurrent status requests in {took_s:.2f} s during a move "
            f"({states.count('moving')} answered while it ran): tick jitter p99 "
            f"{1e3 * p99_s:.2f} ms, max {1e3 * during.max():.2f} ms over {during.size} ticks "
            f"(the witness process meanwhile: p99 {1e3 * machine_p99_s:.2f} ms over {machine.size}; "
            f"other programs used {foreign:.2f} cores)"
        )
        # answered while the move ran: at least a round's worth (the fake world's move may end
        # before a slow burst does: 240 of 500 once on a loaded CI machine)
        assert states.count("moving") >= 100
        if p99_s <= JITTER_GOAL_P99_S:
            break
    assert console.daemon.status()["timing"]["quiet_holds"] > 0  # the console did stand back
    figures = [f"{1e3 * p:.2f} ms (witness: {1e3 * w:.2f} ms, others: {f:.2f} cores)" for p, w, f in attempts]
    best_s = min(p for p, _, _ in attempts)
    quiet = any(w <= JITTER_GOAL_P99_S / 2 and f <= FOREIGN_CORES for _, w, f in attempts)
    if best_s > JITTER_GOAL_P99_S and not quiet:
        pytest.skip(f"this machine was too noisy by itself during every burst: {figures}")
    assert best_s <= JITTER_GOAL_P99_S, figures


def test_the_websocket_authenticates_on_connect(console: Console) -> None:
    from websockets.exceptions import ConnectionClosed, InvalidStatus
    from websockets.sync.client import connect

    url = f"ws://127.0.0.1:{console.server.port}/api/live"
    with connect(url) as ws:
        ws.send(json.dumps({"token": "wrong"}))
        assert json.loads(ws.recv(timeout=5))["error"] == "wrong token"
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=5)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 4401
    with pytest.raises(InvalidStatus) as refused:
        connect(url, origin="http://evil.example")  # type: ignore[arg-type]
    assert refused.value.response.status_code == 403
    with connect(url, origin=console.origin) as ws:  # type: ignore[arg-type]
        ws.send(json.dumps({"token": console.token}))
        messages = [json.loads(ws.recv(timeout=5)) for _ in range(5)]
    assert all(m["type"] == "status" for m in messages)
    assert all(abs(m["time_s"] - time.time()) < 5 for m in messages)
    assert messages[-1]["status"]["position_state"] == "confirmed"
    times = [m["time_s"] for m in messages]
    assert times == sorted(times) and times[-1] - times[0] < 1.0  # pushed, about 30 per second


def test_a_non_loopback_address_needs_allow_remote(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not a loopback address"):
        HttpConfig().listening_on("0.0.0.0:8470", "--http")
    with pytest.raises(InputError, match="HOST:PORT"):
        HttpConfig().listening_on("8470", "--http")
    assert HttpConfig().listening_on("[::1]:0", "--http").host == "::1"
    assert HttpConfig(allow_remote=True).listening_on("0.0.0.0:8470", "--http").host == "0.0.0.0"
    config = tmp_path / "c.toml"
    config.write_text('[http]\nlisten = "192.168.1.5:8470"\n')
    with pytest.raises(InputError, match=r"http\.listen: 192\.168\.1\.5 is not a loopback"):
        load_config(config)
    config.write_text('[http]\nlisten = "192.168.1.5:8470"\nallow_remote = true\norigins = ["https://lab"]\n')
    http = load_config(config).http
    assert http is not None and (http.host, http.port, http.origins) == (
        "192.168.1.5",
        8470,
        ("https://lab",),
    )
    assert load_config(None).http is None  # off by default
    cli = subprocess.run(
        [sys.executable, "-m", "feeder", "daemon", "--http", "0.0.0.0:8470", "--state-dir", str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert cli.returncode == 2 and "--http" in cli.stderr and "allow_remote" in cli.stderr
    assert not (tmp_path / "feeder.sqlite").exists()
