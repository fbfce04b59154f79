"""The host heartbeat follows the caller's control loop (``Amplifier.alive``), not the process.

A hung daemon (deadlocked, stopped) must stop beating so the drive's host watchdog trips:
the link beats from a thread of its own, and once ``alive()`` was called only while the
last call is younger than ``HOST_SILENCE_PERIODS - 1`` periods.  Against firmware_sim's node
on python-can's ``virtual`` bus.
"""

from __future__ import annotations

import itertools
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import can
import canopen
import pytest
from test_daemon_doubles import FakeAmplifier, FakeSensor, FakeWorld

from feeder.daemon.control_loop import COARSE, FINE, ControlLoop, LoopSettings, StepMode
from feeder.daemon.links import CAN_KEYS
from feeder.drivers.amplifier import AmplifierError, DriveSettings
from feeder.drivers.canopen import CanopenAmplifier
from feeder.drivers.canopen_heartbeat import HOST_SILENCE_PERIODS
from feeder.errors import InputError
from firmware_sim.canopen_node import CanopenNode
from firmware_sim.clock import RealTimeClock
from firmware_sim.firmware import Firmware, FirmwareConfig

pytestmark = pytest.mark.timeout(60)
NODE_ID = 5
HEARTBEAT_S = 0.2  # generous: a loaded test machine can starve threads
FRESH_S = (HOST_SILENCE_PERIODS - 1) * HEARTBEAT_S
"""How long one alive() keeps the host beating."""
SLACK_S = 0.1
FAST = DriveSettings(frequency_hz=1000.0, amplitude_v=40.0, flyback_shape="linear", flyback_s=100e-6)


@dataclass
class Rig:
    firmware: Firmware
    node: CanopenNode
    channel: str
    bus: dict[str, Any]


@pytest.fixture
def rig() -> Iterator[Rig]:
    channel = f"test-canopen-host-heartbeat-{uuid.uuid4().hex}"
    firmware = Firmware(FirmwareConfig(watchdog_s=5.0))  # in-process: a loaded CI stalls its tick
    stop = threading.Event()
    ticker = threading.Thread(target=firmware.run, args=(RealTimeClock(), stop), daemon=True)
    ticker.start()
    node = CanopenNode(firmware, 1, NODE_ID, can.Bus(interface="virtual", channel=channel)).start()
    yield Rig(firmware, node, channel, {"interface": "virtual", "channel": channel})
    node.close()
    stop.set()
    ticker.join(timeout=2.0)


def open_amp(rig: Rig, **options: Any) -> CanopenAmplifier:
    return CanopenAmplifier(
        rig.bus, NODE_ID, heartbeat_s=HEARTBEAT_S, timeout_s=0.5, supervise_host=True, **options
    )


class HostBeats:
    """Receives the host's heartbeats (COB-ID 0x700 + host id) on the virtual bus, with their
    arrival times (``time.monotonic()``)."""

    def __init__(self, channel: str, host_id: int = 127) -> None:
        self.cob_id = 0x700 + host_id
        self.times: list[float] = []
        self._bus = can.Bus(interface="virtual", channel=channel)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            frame = self._bus.recv(0.02)
            if frame is not None and frame.arbitration_id == self.cob_id:
                assert bytes(frame.data) == b"\x05"  # OPERATIONAL
                self.times.append(time.monotonic())

    def between(self, start: float, end: float) -> list[float]:
        return [t for t in self.times if start <= t < end]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self._bus.shutdown()


class Loop:
    """A control loop's liveness: calls ``amp.alive()`` every 20 ms until :meth:`stall`."""

    def __init__(self, amp: CanopenAmplifier) -> None:
        self.amp = amp
        self.last = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self.amp.alive()
            self.last = time.monotonic()
            self._stop.wait(0.02)

    def stall(self) -> float:
        """Stop calling alive(); the time of the last call."""
        self._stop.set()
        self._thread.join(timeout=1.0)
        return self.last


def test_heartbeats_go_on_while_the_loop_is_alive_and_stop_when_it_stalls(rig: Rig) -> None:
    beats = HostBeats(rig.channel)
    amp = open_amp(rig)
    try:
        loop = Loop(amp)
        start = time.monotonic()
        time.sleep(1.5)
        alive = beats.between(start, time.monotonic())
        assert len(alive) >= 1.5 / HEARTBEAT_S - 2
        assert max(b - a for a, b in itertools.pairwise(alive)) < 2 * HEARTBEAT_S
        last_alive = loop.stall()
        time.sleep(FRESH_S + 1.0)
        after = beats.between(last_alive, time.monotonic())
        # the last beat goes out within HOST_SILENCE_PERIODS - 1 periods of the last alive()
        assert all(t <= last_alive + FRESH_S + SLACK_S for t in after), (last_alive, after)
        assert len(after) <= HOST_SILENCE_PERIODS
        assert not beats.between(last_alive + FRESH_S + SLACK_S, time.monotonic())
        # the loop resumes: so does the heartbeat, at once
        resumed = time.monotonic()
        loop = Loop(amp)
        time.sleep(HEARTBEAT_S + SLACK_S)
        assert beats.between(resumed, time.monotonic())
        loop.stall()
    finally:
        amp.close()
        beats.close()


def test_before_the_first_alive_the_host_beats_unconditionally(rig: Rig) -> None:
    """CLI tools and tests run no control loop and never call alive()."""
    beats = HostBeats(rig.channel)
    amp = open_amp(rig)
    try:
        start = time.monotonic()
        time.sleep(1.5)
        assert len(beats.between(start, time.monotonic())) >= 1.5 / HEARTBEAT_S - 2
    finally:
        amp.close()
        beats.close()


def test_a_stalled_loop_in_a_live_process_gets_the_moving_axis_grounded(rig: Rig) -> None:
    """The audit's case: the process lives (its threads run) but its control loop is hung."""
    amp, axis = open_amp(rig), rig.firmware.axis(1)
    try:
        loop = Loop(amp)
        amp.apply(FAST)
        amp.enable()
        amp.run_continuous(forward=True)
        time.sleep(HOST_SILENCE_PERIODS * HEARTBEAT_S + 0.5)  # longer than the consumer time
        assert axis.status().moving and axis.status().fault_word == 0  # alive: left alone
        loop.stall()
        deadline = time.monotonic() + FRESH_S + HOST_SILENCE_PERIODS * HEARTBEAT_S + 2.0
        while not axis.status().fault_word and time.monotonic() < deadline:
            time.sleep(0.01)
        status = axis.status()
        assert (status.faults, status.mode) == (("host_watchdog",), "gnd")
        assert amp.lost is None  # the link itself is fine: the node still beats
        with pytest.raises(AmplifierError, match="EMCY 0x8130 host watchdog on axis 1"):
            amp.wait(2.0)  # and the node's EMCY reaches the driver
    finally:
        amp.close()


def test_the_host_heartbeat_is_not_the_kernels_broadcast_manager(
    rig: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """python-can's send_periodic is SocketCAN's BCM: it beats for a stopped process."""

    original = canopen.Network.send_periodic

    def send_periodic(network: canopen.Network, can_id: int, *args: Any, **kwargs: Any) -> Any:
        assert can_id != 0x700 + 127, "the host heartbeat must not use send_periodic"
        return original(network, can_id, *args, **kwargs)  # the simulated node's own heartbeat

    monkeypatch.setattr(canopen.Network, "send_periodic", send_periodic)
    beats = HostBeats(rig.channel)
    amp = open_amp(rig)
    try:
        time.sleep(3 * HEARTBEAT_S)
        assert beats.times
    finally:
        amp.close()
        beats.close()


def test_the_configured_host_id_is_the_one_the_host_beats_as(rig: Rig) -> None:
    """``[amplifier.can] host_id`` (the daemon passes it; python-can never sees it: links.CAN_KEYS)."""
    assert "host_id" in CAN_KEYS
    beats = HostBeats(rig.channel, host_id=100)
    amp = CanopenAmplifier(
        rig.bus, NODE_ID, heartbeat_s=HEARTBEAT_S, timeout_s=0.5, supervise_host=True, host_id=100
    )
    try:
        assert amp.link.host_id == 100 and rig.node._consumer_id == 100
        time.sleep(3 * HEARTBEAT_S)
        assert beats.times
    finally:
        amp.close()
        beats.close()


@pytest.mark.parametrize("host_id", [NODE_ID, 0, 128])
def test_a_host_id_that_is_the_nodes_or_out_of_range_is_refused(rig: Rig, host_id: int) -> None:
    with pytest.raises(InputError, match="host_id"):
        open_amp(rig, host_id=host_id)


# -- the daemon's loop calls alive() on every tick --------------------------------------------

MODES = {
    COARSE: StepMode(COARSE, DriveSettings(1000.0, 100.0), 3.45e-6, (2.8e-6, 4.1e-6)),
    FINE: StepMode(FINE, DriveSettings(1000.0, 40.0), 0.8e-6, (0.5e-6, 1.1e-6)),
}


class CountingAmplifier(FakeAmplifier):
    def __init__(self, world: FakeWorld) -> None:
        super().__init__(world)
        self.alive_calls = 0

    def alive(self) -> None:
        self.alive_calls += 1


def test_the_control_loop_says_alive_on_every_tick_to_every_axis() -> None:
    world = FakeWorld({(100.0, 1): 3e-6, (100.0, -1): 3e-6, (40.0, 1): 1e-6, (40.0, -1): 1e-6})
    amps = {name: CountingAmplifier(world) for name in ("x", "y", "theta")}
    loop = ControlLoop(amps, FakeSensor(world), MODES, LoopSettings(rate_hz=100.0))
    loop.start()
    try:
        time.sleep(0.5)
    finally:
        loop.shutdown()
    ticks = loop.ticks
    assert ticks >= 10
    assert all(abs(amp.alive_calls - ticks) <= 1 for amp in amps.values()), (
        ticks,
        [a.alive_calls for a in amps.values()],
    )
