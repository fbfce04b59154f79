"""``[amplifier.can]`` checks for real CAN hardware: a bit rate for adapters that take it from
the host, the host's node id, and the drive's rating (never the simulator's by default)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import cast

import pytest

from feeder.daemon.config import DEFAULT_MODELS
from feeder.daemon.config_file import CAN_HOST_SETS_BITRATE, load_config
from feeder.daemon.launcher import Simulator
from feeder.daemon.links import simulator_addresses
from feeder.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
SENSOR = '[sensor]\naddress = "socket://127.0.0.1:7240"\n'


def can_config(tmp_path: Path, can: str, amplifier: str = 'model = "firmware_sim"\n') -> Path:
    path = tmp_path / "feeder.toml"
    path.write_text(f'[amplifier]\ntransport = "can"\n{amplifier}[amplifier.can]\n{can}{SENSOR}')
    return path


def refusal(path: Path) -> str:
    with pytest.raises(InputError) as err:
        load_config(path)
    message = str(err.value)
    assert "\n" not in message and str(path) in message
    return message


# -- item 2: a bit rate for adapters that take it from the host ---------------------------------


@pytest.mark.parametrize("interface", sorted(CAN_HOST_SETS_BITRATE))
def test_an_adapter_that_takes_its_bit_rate_from_the_host_needs_one(tmp_path: Path, interface: str) -> None:
    path = can_config(tmp_path, f'interface = "{interface}"\nchannel = "0"\n')
    message = refusal(path)
    assert "amplifier.can.bitrate" in message and interface in message


@pytest.mark.parametrize("rate", ["bitrate = 250000", "btr = 0x011C", 'timing = "x"'])
def test_any_of_bitrate_btr_timing_will_do(tmp_path: Path, rate: str) -> None:
    config = load_config(can_config(tmp_path, f'interface = "slcan"\nchannel = "/dev/ttyACM0"\n{rate}\n'))
    assert not config.amplifier.simulated


@pytest.mark.parametrize("interface", ["socketcan", "virtual"])
def test_socketcan_and_virtual_need_no_bit_rate(tmp_path: Path, interface: str) -> None:
    config = load_config(can_config(tmp_path, f'interface = "{interface}"\nchannel = "can0"\n'))
    assert config.amplifier.can == {"interface": interface, "channel": "can0"}


def test_the_simulators_configuration_passes_a_bit_rate() -> None:
    """No channel: the daemon starts firmware_sim and opens its slcan pty with a bit rate."""
    config = load_config(None).with_transport("can")
    assert config.amplifier.simulated
    endpoints = {"slcan_pty": "/dev/pts/9", "sensor_tcp": "socket://127.0.0.1:1"}
    address, _ = simulator_addresses(config, cast(Simulator, SimpleNamespace(endpoints=endpoints)))
    assert isinstance(address, dict) and address["interface"] == "slcan" and address["bitrate"] == 500_000


# -- item 3: the host's node id -------------------------------------------------------------------


def test_host_id_is_configurable_and_defaults_to_127(tmp_path: Path) -> None:
    config = load_config(can_config(tmp_path, 'interface = "socketcan"\nchannel = "can0"\nhost_id = 100\n'))
    assert config.amplifier.can["host_id"] == 100  # links.py passes it to the driver
    assert (
        "host_id"
        not in load_config(can_config(tmp_path, 'interface = "socketcan"\nchannel = "can0"\n')).amplifier.can
    )


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ("0", "amplifier.can.host_id = 0 is outside [1, 127]"),
        ("128", "amplifier.can.host_id = 128 is outside [1, 127]"),
        ("true", "amplifier.can.host_id must be an integer"),
        ('"127"', "amplifier.can.host_id must be an integer"),
        ("4\nnode_id = 4", "amplifier.can.host_id = 4 is the amplifier's (it uses node 4)"),
    ],
)
def test_a_bad_host_id_is_refused_by_name(tmp_path: Path, value: str, words: str) -> None:
    path = can_config(tmp_path, f'interface = "socketcan"\nchannel = "can0"\nhost_id = {value}\n')
    assert words in refusal(path)


def test_the_default_host_id_must_not_be_one_of_the_planes_nodes(tmp_path: Path) -> None:
    """One node per axis from 125: axes 1..3 are nodes 125..127, the default host id's."""
    path = can_config(tmp_path, 'interface = "socketcan"\nchannel = "can0"\nnode_id = 125\n')
    path.write_text(path.read_text() + '[plate]\naxes = ["x", "y", "theta"]\n')  # located by the stream
    assert "amplifier.can.host_id = 127 is the amplifier's (it uses nodes 125..127)" in refusal(path)
    path.write_text(path.read_text().replace("node_id = 125\n", "node_id = 125\nhost_id = 100\n"))
    assert load_config(path).amplifier.can["host_id"] == 100
    # a three-axis node uses one id; without supervise_host the host does not beat at all
    three = path.read_text().replace("host_id = 100\n", 'eds = "feeder_amplifier_3axis.eds"\n')
    path.write_text(three)
    load_config(path)
    path.write_text(three.replace("node_id = 125\n", "node_id = 127\n"))
    assert "it uses node 127" in refusal(path)
    path.write_text(three.replace("node_id = 125\n", "node_id = 127\nsupervise_host = false\n"))
    load_config(path)


# -- item 5: a CAN drive's rating -------------------------------------------------------------------


def test_a_can_drive_without_a_model_or_limits_is_refused(tmp_path: Path) -> None:
    path = can_config(tmp_path, 'interface = "socketcan"\nchannel = "can0"\n', amplifier="")
    assert refusal(path).endswith(
        "amplifier.model: a CAN drive needs its rating: model = ... or [amplifier.limits]"
    )


def test_a_can_drive_with_a_model_or_limits_is_taken(tmp_path: Path) -> None:
    can = 'interface = "socketcan"\nchannel = "can0"\n'
    assert load_config(can_config(tmp_path, can, 'model = "anc300"\n')).amplifier.model == "anc300"
    limits = "[amplifier.limits]\nv_max_v = 100.0\n"
    config = load_config(can_config(tmp_path, can, limits))
    assert config.amplifier.limits.v_max_v == 100.0


def test_the_simulator_keeps_its_default_rating(tmp_path: Path) -> None:
    path = tmp_path / "sim.toml"
    path.write_text('[amplifier]\ntransport = "can"\n[amplifier.can]\nnode_id = 2\n')
    config = load_config(path)
    assert config.amplifier.simulated and config.amplifier.model == DEFAULT_MODELS["can"] == "firmware_sim"
    assert load_config(None).with_transport("can").amplifier.model == "firmware_sim"
