"""Shared test fixtures: repository paths and the ``--runslow`` option."""

from __future__ import annotations

import shutil
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import settings

from firmware_sim.clock import RealTimeClock
from firmware_sim.firmware import Firmware

# CI runs the property tests on a fixed sequence of examples (a red run is then reproducible);
# `--hypothesis-profile=explore` draws new ones.
settings.register_profile("ci", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile("ci")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--runslow", action="store_true", help="also run tests marked slow (soak, fuzz)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` beside the repository (DESIGN.md, paper, AFM files)."""
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} not found (CI clones the repo with shared/ beside it)")
    return SHARED


@pytest.fixture
def short_dir() -> Iterator[Path]:
    """A fresh directory under /tmp, short enough for Unix socket paths (under 108 bytes)."""
    path = Path(tempfile.mkdtemp(prefix="fd"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def ticking() -> Iterator[Firmware]:
    """A firmware whose tick runs on the real-time clock in a thread of its own."""
    fw = Firmware()
    stop = threading.Event()
    thread = threading.Thread(target=fw.run, args=(RealTimeClock(), stop), daemon=True)
    thread.start()
    yield fw
    fw.shutdown()  # wakes any stepw a failing test left waiting
    stop.set()
    thread.join(timeout=5)
