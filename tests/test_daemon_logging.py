"""The daemon's logging (feeder/cli/daemon.py): stderr and daemon.log at the chosen level, the
libraries' chatter (canopen's INFO per SDO and PDO set-up) kept to warnings unless debugging."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import pytest

from feeder.cli.daemon import QUIET_LIBRARIES, setup_logging


@pytest.fixture
def restore_logging() -> Iterator[None]:
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    levels = {name: logging.getLogger(name).level for name in QUIET_LIBRARIES}
    yield
    for handler in root.handlers:
        if handler not in handlers:
            handler.close()
    root.handlers[:], root.level = handlers, level
    for name, old in levels.items():
        logging.getLogger(name).setLevel(old)


@pytest.mark.usefixtures("restore_logging")
@pytest.mark.parametrize(("level", "chatter_logged"), [("info", False), ("debug", True)])
def test_canopen_chatter_is_kept_out_unless_debugging(
    tmp_path: Path, level: str, chatter_logged: bool
) -> None:
    log_file = tmp_path / "state" / "daemon.log"
    setup_logging(level, log_file)
    logging.getLogger("canopen.pdo.base").info("Setting COB-ID 0x181 and temporarily disabling PDO")
    logging.getLogger("canopen.sdo.client").warning("SDO abort")
    logging.getLogger("feeder.daemon.service").info("serving")
    for handler in logging.getLogger().handlers:
        handler.flush()
    text = log_file.read_text()
    assert ("temporarily disabling PDO" in text) is chatter_logged
    assert "SDO abort" in text and "serving" in text
    assert log_file.stat().st_mode & 0o777 == 0o600
