"""``python -m firmware_sim``: options, bad input, ready line, virtual clock, clean shutdown."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from feeder.contact.breakaway import DEFAULT_TAU_PA
from feeder.daemon.launcher import LaunchError, Simulator
from feeder.drivers.anc300_link import Anc300Link

pytestmark = pytest.mark.timeout(120)


def run_main(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "firmware_sim", *args], capture_output=True, text=True, timeout=60
    )


def test_help_documents_the_startup_options() -> None:
    result = run_main("--help")
    assert result.returncode == 0
    for option in (
        "--console",
        "--sensor",
        "--clock",
        "--tau-offset",
        "--tau-pa",
        "--seed",
        "--part",
        "--serial-login",
        "--dac-buffer-s",
        "--camera-noise-m",
        "--camera-width-px",
        "--camera-height-px",
    ):
        assert option in result.stdout


@pytest.mark.parametrize(
    "args",
    [
        ["--console", "tcp:0.0.0.0:0"],
        ["--console", "udp:x"],
        ["--part", "banana"],
        ["--axes", "9"],
        ["--camera-width-px", "8"],
    ],
)
def test_bad_options_exit_2_with_one_line(args: list[str]) -> None:
    result = run_main(*args)
    assert result.returncode == 2
    assert result.stdout == ""
    assert len(result.stderr.strip().splitlines()) == 1


def test_virtual_clock_tau_offset_and_clean_shutdown(tmp_path: Path) -> None:
    log = tmp_path / "firmware_sim.log"
    sim = Simulator(["--clock", "virtual", "--tau-offset", "0.15", "--seed", "3"], log_path=log)
    try:
        assert sim.ready["clock"] == "virtual"
        assert sim.ready["true"]["tau_pa"] == pytest.approx(1.15 * DEFAULT_TAU_PA)
        link = Anc300Link(sim.endpoints["console_pty"], timeout_s=30.0)
        for command in ("setv 1 200", "setm 1 stp", "stepu 1 500", "stepw 1"):
            link.query(command)
        assert link.value("getcnt 1", "steps") == "500"
        link.query("stepu 1 c")
        link.close()
        sim.process.terminate()
        sim.process.wait(timeout=30)
    finally:
        sim.stop()
    assert sim.process.returncode == 0
    final = json.loads(log.read_text().strip().splitlines()[-1])
    assert final["stopped"] is True and final["tick"]["ticks"] >= 5_000  # ≥ 5 s of virtual time at 1 kHz


def test_a_simulator_late_with_its_ready_line_is_stopped_with_the_likely_reason() -> None:
    """No ready line in time: the child is stopped and the error says a first start compiles the
    plant's kernels, and how to do that ahead."""
    with pytest.raises(LaunchError, match=r"within 0\.01 s .*feeder\.plant\.warm_kernels") as caught:
        Simulator(["--clock", "virtual"], timeout_s=0.01)
    assert "compiles them" in str(caught.value)
