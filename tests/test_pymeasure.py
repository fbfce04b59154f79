"""Interoperability: pymeasure's ANC300Controller (pyvisa-py) drives firmware_sim unchanged.

Over TCP (``TCPIP::127.0.0.1::PORT::SOCKET``, login as on a real unit) and over
the pty (``ASRL/dev/pts/N::INSTR``; pymeasure always sends the password, so the
simulator runs with ``--serial-login``).
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from feeder.daemon.launcher import Simulator

pymeasure_anc300 = pytest.importorskip("pymeasure.instruments.attocube")
pytest.importorskip("pyvisa_py")

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def sim() -> Iterator[Simulator]:
    simulator = Simulator(
        ["--console", "pty", "--serial-login", "--console", "tcp:127.0.0.1:0", "--axes", "2"]
    )
    yield simulator
    simulator.stop()


def resources(sim: Simulator) -> dict[str, str]:
    port = sim.endpoints["console_tcp"].rsplit(":", 1)[1]
    return {"tcp": f"TCPIP::127.0.0.1::{port}::SOCKET", "pty": f"ASRL{sim.endpoints['console_pty']}::INSTR"}


@pytest.mark.parametrize("link", ["tcp", "pty"])
def test_anc300controller_configures_and_steps_an_axis(sim: Simulator, link: str) -> None:
    controller = pymeasure_anc300.ANC300Controller(
        resources(sim)[link], axisnames=["x", "y"], passwd="123456", visa_library="@py"
    )
    try:
        assert controller.version.startswith("attocube ANC300")
        axis = controller.y
        axis.frequency = 250
        axis.voltage = 42.5
        assert (axis.frequency, axis.voltage) == (250, 42.5)
        axis.pattern_up = [min(255, 2 * i) for i in range(256)]
        assert axis.pattern_up == [min(255, 2 * i) for i in range(256)]
        axis.mode = "stp"
        assert axis.mode == "stp"
        axis.move(-12, gnd=True)  # blocking: mode stp, stepd, stepw, then ground
        assert axis.mode == "gnd"
        assert int(controller.ask("getcnt 2").split("=")[1]) <= -12
        axis.mode = "stp"
        axis.move_raw(float("inf"))
        axis.stop()
        with pytest.raises(ValueError, match="wrong mode"):
            controller.x.move_raw(5)  # axis 1 is grounded: the unit refuses
        assert axis.capacity > 0
        assert controller.x.serial_nr.startswith("FS")
        controller.ground_all()
    finally:
        controller.adapter.close()


def test_wrong_password_is_refused_over_tcp(sim: Simulator) -> None:
    with pytest.raises(Exception, match="authorization failed"):
        pymeasure_anc300.ANC300Controller(
            resources(sim)["tcp"], axisnames=["x"], passwd="000000", visa_library="@py"
        )
