"""The shutdown while the daemon's camera calibration moves the plate (found by a review of the
daemon's threads; each test holds the calibration's thread at the critical point)."""

from __future__ import annotations

import logging
import sqlite3
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_daemon_doubles import FakeWorld
from test_daemon_service import CONFIGURED, TRUE, FakeLinks, make_setup

from feeder.daemon import service
from feeder.daemon.service import Daemon
from feeder.daemon.store import Store
from feeder.errors import FeederError
from feeder.vision.offset_moves import MovesStopped, OffsetMoves

pytestmark = pytest.mark.timeout(60)

REPORT = {
    "pixel_size_m": 1.1e-6,
    "rotation_rad": 0.3,
    "mirrored": True,
    "origin_x_px": None,
    "origin_y_px": None,
    "returned_px": 0.1,
    "slipped": False,
}
"""What a finished calibration reports, as far as the daemon reads it."""


class Calibrating:
    """A daemon on fake links with a camera, and its camera calibration on a thread of its own:
    the error it ended with, or None."""

    def __init__(self, base: Path) -> None:
        self.links = FakeLinks(FakeWorld(TRUE, seed=3))
        self.links.configured = CONFIGURED
        self.daemon = Daemon(self.links, make_setup(base))
        self.daemon.start()
        self.ended: list[BaseException | None] = []
        self.thread = threading.Thread(target=self._calibrate, name="camera-calibration")

    def _calibrate(self) -> None:
        try:
            self.daemon.camera_moves(OffsetMoves(stack_gain_m_per_v=0.07e-6), save=True)
        except (FeederError, sqlite3.Error) as err:  # sqlite3's: the store closed under it
            self.ended.append(err)
        else:
            self.ended.append(None)

    def shut_down(self) -> threading.Thread:
        shutting = threading.Thread(target=self.daemon.shutdown, name="shutdown")
        shutting.start()
        return shutting


@pytest.fixture
def service_log() -> Iterator[logging.Logger]:
    logger = logging.getLogger(service.__name__)
    level = logger.level
    logger.setLevel(logging.INFO)
    yield logger
    logger.setLevel(level)


class _Said(logging.Handler):
    """Sets ``events`` when a record's message starts with ``prefix``."""

    def __init__(self, prefix: str, *events: threading.Event) -> None:
        super().__init__(logging.INFO)
        self.prefix = prefix
        self.events = events

    def emit(self, record: logging.LogRecord) -> None:
        if record.getMessage().startswith(self.prefix):
            for event in self.events:
                event.set()


def test_the_shutdown_waits_for_the_camera_calibration_it_stopped(
    short_dir: Path, monkeypatch: pytest.MonkeyPatch, service_log: logging.Logger
) -> None:
    """The calibration ends as the shutdown begins (its last moves grounding the axes, its report
    to store).  The shutdown stopped it but did not wait: it closed the amplifier the calibration
    still grounded and the store the finished calibration was to go into (a raw
    sqlite3.ProgrammingError on the calibration's thread, nothing stored)."""
    run = Calibrating(short_dir)
    amplifier = run.links.amplifiers[0]
    started, closed, waits, either = (threading.Event() for _ in range(4))
    close = run.daemon.store.close

    def closing() -> None:
        close()
        closed.set()
        either.set()

    run.daemon.store.close = closing  # type: ignore[method-assign]
    said = _Said("shutdown: waiting", waits, either)
    seen: dict[str, bool] = {}

    def held_measure(amplifiers: Any, sensor: Any, located: Any, moves: Any, progress: Any, stop: Any) -> Any:
        started.set()
        assert stop.wait(10), "the shutdown stops the calibration's moves"
        assert either.wait(10), "the shutdown neither waited nor closed the store"
        seen["store closed"] = closed.is_set()
        seen["link closed"] = "close" in amplifier.calls
        amplifiers["x"].ground()  # the moves ground every axis as they end
        return dict(REPORT)

    monkeypatch.setattr(service, "measure", held_measure)
    service_log.addHandler(said)
    try:
        run.thread.start()
        assert started.wait(10)
        shutting = run.shut_down()
        run.thread.join(30)
        shutting.join(30)
    finally:
        service_log.removeHandler(said)
        if not run.daemon.wait(0):
            run.daemon.shutdown()
    assert seen == {"store closed": False, "link closed": False}
    assert not shutting.is_alive() and run.ended == [None]
    assert waits.is_set()
    store = Store(short_dir / "state" / "f.sqlite")
    try:
        stored = store.camera_calibration()
    finally:
        store.close()
    assert stored is not None and stored["pixel_size_m"] == REPORT["pixel_size_m"]


def test_a_camera_calibration_that_does_not_end_is_logged_and_the_shutdown_goes_on(
    short_dir: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """The shutdown's wait is bounded: a calibration that does not end (a hung link) is named in
    the log, and the daemon shuts down all the same."""
    monkeypatch.setattr(service, "CAMERA_MOVES_END_S", 0.1, raising=False)
    run = Calibrating(short_dir)
    started, release = threading.Event(), threading.Event()

    def hung_measure(amplifiers: Any, sensor: Any, located: Any, moves: Any, progress: Any, stop: Any) -> Any:
        started.set()
        assert release.wait(30)
        raise MovesStopped("the moves were stopped: every axis grounded, nothing measured")

    monkeypatch.setattr(service, "measure", hung_measure)
    caplog.set_level(logging.INFO, logger=service.__name__)
    run.thread.start()
    try:
        assert started.wait(10)
        shutting = run.shut_down()
        shutting.join(30)
        assert not shutting.is_alive()
    finally:
        release.set()
        run.thread.join(30)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("the camera calibration did not end within 0.1 s of its stop" in w for w in warnings), warnings
    assert len(run.ended) == 1 and isinstance(run.ended[0], MovesStopped)
