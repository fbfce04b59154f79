"""A process that stood still (SIGSTOP, a suspended machine) does not blame its peers: the
verification review stopped the daemon for 2.5 s mid-move, and it then declared its camera ("no
poses within 2 s") and its CANopen nodes ("no heartbeat for 2644 ms") lost, though their frames
were waiting in its buffers.  Here the process stands still in-process: the test thread holds the
GIL (a long switch interval) so no other thread runs, as under SIGSTOP."""

from __future__ import annotations

import contextlib
import sys
import threading
import time
import uuid
from collections.abc import Iterator

import can
import pytest
from test_control_loop import TRUE
from test_daemon_doubles import FakeSensor, FakeWorld

from feeder import stall
from feeder.daemon.sensor_feed import SensorFeed
from feeder.drivers.canopen import CanopenAmplifier
from feeder.drivers.canopen_link import HEARTBEAT_LOSS_PERIODS
from feeder.drivers.sensor import PositionSample, SensorLost
from firmware_sim.canopen_node import CanopenNode
from firmware_sim.clock import RealTimeClock
from firmware_sim.firmware import Firmware

pytestmark = pytest.mark.timeout(60)


@contextlib.contextmanager
def standing_still(seconds: float) -> Iterator[None]:
    """No other Python thread runs for ``seconds`` (this one keeps the GIL), then all resume."""
    interval = sys.getswitchinterval()
    sys.setswitchinterval(10.0)
    try:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            pass
        yield
    finally:
        sys.setswitchinterval(interval)


def test_the_monitor_sees_the_process_stand_still_and_only_then() -> None:
    stall.watch()
    time.sleep(0.2)
    before = time.monotonic()
    time.sleep(0.3)
    assert stall.stalled_since(before) == 0.0  # a sleep is no stall
    with standing_still(0.8):
        pass
    time.sleep(0.1)  # the monitor runs again and notes the gap
    assert 0.5 <= stall.stalled_since(before) <= 0.9
    assert stall.stalled_since(time.monotonic()) == 0.0


class QuietSensor(FakeSensor):
    """A camera whose frames stop until ``resume`` is set (the review's: they waited in a buffer)."""

    def __init__(self) -> None:
        super().__init__(FakeWorld(TRUE))
        self.resume = threading.Event()

    def read(self, timeout_s: float = 1.0) -> PositionSample:
        if not self.resume.wait(timeout_s):
            raise SensorLost(f"no poses within {timeout_s:g} s")
        return super().read(timeout_s)


def test_a_sensor_silent_only_while_the_process_stood_still_is_not_lost() -> None:
    sensor = QuietSensor()
    feed = SensorFeed(sensor, 0.3, time.monotonic)
    try:
        time.sleep(0.05)  # the feed is waiting on the sensor
        with standing_still(0.8):  # its 0.3 s ran out while nothing ran
            sensor.resume.set()  # the frames were there all along
        time.sleep(0.3)
        assert feed.lost is None and feed.take()
    finally:
        feed.close()
    silent = QuietSensor()  # a camera that is really gone is still lost
    feed = SensorFeed(silent, 0.3, time.monotonic)
    try:
        time.sleep(0.6)
        assert feed.lost is not None and "no poses" in feed.lost
    finally:
        feed.close()


def test_a_canopen_node_is_not_declared_lost_for_the_hosts_own_standstill() -> None:
    channel = f"test-stall-{uuid.uuid4().hex}"
    firmware = Firmware()
    stop = threading.Event()
    ticker = threading.Thread(target=firmware.run, args=(RealTimeClock(), stop), daemon=True)
    ticker.start()
    node = CanopenNode(firmware, 1, 5, can.Bus(interface="virtual", channel=channel)).start()
    amp = CanopenAmplifier({"interface": "virtual", "channel": channel}, 5, heartbeat_s=0.2, timeout_s=0.5)
    try:
        with standing_still(3 * HEARTBEAT_LOSS_PERIODS * 0.2):  # 1.5 s: three loss limits
            pass
        time.sleep(0.5)
        assert amp.link.lost is None
        amp.status()  # and it answers
    finally:
        amp.close()
        node.close()
        stop.set()
        ticker.join(timeout=2.0)


def test_a_late_tick_is_blamed_on_this_process_only_when_it_used_the_cpu_meanwhile() -> None:
    """The CLI audit saw "the process stood still (SIGSTOP, …)" at a `feeder daemon` start on a
    loaded host: a cause the message could not know.  The CPU the process used while the tick
    was due tells a process busy itself (its own threads) from one stopped or starved."""
    assert stall.why_late(0.3, 0.28).startswith("this process kept the interpreter busy (0.28 s of CPU")
    assert stall.why_late(2.5, 0.01).startswith("the process stood still or got no CPU (SIGSTOP")
