"""The daemon's TOML configuration: defaults, a full file, and one-line refusals."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from feeder.daemon.config import DaemonConfig, default_socket_path, default_state_dir, load_config
from feeder.daemon.links import open_links, simulator_args
from feeder.errors import InputError

ROOT = Path(__file__).resolve().parents[1]

FULL = """
[amplifier]
transport = "can"
axis = 2
timeout_s = 0.5
[amplifier.limits]
v_max_v = 150.0
current_limit_a = 0.3
[amplifier.can]
interface = "socketcan"
channel = "can0"
node_id = 4

[sensor]
address = "socket://127.0.0.1:7240"
timeout_s = 2.0

[part]
size = "500x500x50"
support = "grooved"
tau_pa = 20e9

[control]
tolerance_m = 0.5e-6
min_position_m = -1e-3
max_position_m = 2e-3
average_samples = 5

[state]
dir = "/tmp/feeder-state-test"
socket = "/tmp/feeder-test.sock"
"""


def test_defaults_follow_xdg(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_STATE_HOME", "/x/state")
    monkeypatch.setenv("XDG_RUNTIME_DIR", "/x/run")
    assert default_state_dir() == Path("/x/state/feeder")
    assert default_socket_path() == Path("/x/run/feeder/feeder.sock")
    monkeypatch.delenv("XDG_RUNTIME_DIR")
    assert default_socket_path() == Path(f"/tmp/feeder-{os.getuid()}/feeder.sock")
    config = load_config(None)
    assert config.amplifier.simulated and config.sensor_address is None
    assert config.loop.tolerance_m == 1e-6 and config.part.label == "300x300x50"


def test_full_file(tmp_path: Path) -> None:
    path = tmp_path / "feeder.toml"
    path.write_text(FULL)
    config = load_config(path)
    assert config.amplifier.transport == "can" and not config.amplifier.simulated
    assert config.amplifier.axis == 2 and config.amplifier.limits.v_max_v == 150.0
    assert config.amplifier.limits.current_limit_a == 0.3
    assert config.amplifier.can == {"interface": "socketcan", "channel": "can0", "node_id": 4}
    assert config.sensor_address == "socket://127.0.0.1:7240"
    assert config.part.label == "500x500x50" and config.support.kind == "grooved"
    assert config.tau_pa == 20e9
    assert config.loop.tolerance_m == 0.5e-6 and config.loop.average_samples == 5
    assert (config.loop.min_position_m, config.loop.max_position_m) == (-1e-3, 2e-3)
    assert config.socket_path == Path("/tmp/feeder-test.sock")


@pytest.mark.parametrize("text, words", [
    ("[motor]\nx = 1", "unknown section [motor]"),
    ("[amplifier]\ntransport = 'usb'", "amplifier.transport"),
    ("[amplifier]\naxis = 0", "amplifier.axis"),
    ("[amplifier.limits]\nv_max_v = -5.0", "v_max_v"),
    ("[amplifier.limits]\nvolts = 5.0", "amplifier.limits.volts"),
    ("[control]\ntolerance_m = -1e-6", "tolerance_m"),
    ("[control]\ntolerance_m = 'small'", "tolerance_m"),
    ("[control]\nspeed = 3", "control.speed"),
    ("[control]\naverage_samples = 2.5", "average_samples"),
    ("[control]\nmin_position_m = 1e-3\nmax_position_m = 0.0", "min_position_m"),
    ("[part]\nsize = '300x300'", "--part"),
    ("not toml [", "not valid TOML"),
])
def test_bad_files_name_the_key(tmp_path: Path, text: str, words: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        load_config(path)
    assert words in str(err.value)


def test_half_named_hardware_is_refused() -> None:
    config = DaemonConfig(sensor_address="socket://127.0.0.1:1")
    with pytest.raises(InputError, match="neither"):
        open_links(config)


def test_simulator_gets_our_part_and_amplifier_rating(tmp_path: Path) -> None:
    path = tmp_path / "sim.toml"
    path.write_text("[part]\nsize = '200x100x50'\n[amplifier.limits]\nv_max_v = 120.0\n"
                    "[simulator]\nargs = ['--seed', '9']\n")
    args = simulator_args(load_config(path))
    assert args[args.index("--part") + 1] == "200x100x50"
    assert float(args[args.index("--v-max") + 1]) == 120.0
    assert args[-2:] == ["--seed", "9"]
    assert "--can" not in args
    assert "--can" in simulator_args(load_config(path).with_transport("can"))


def test_feeder_daemon_with_a_bad_config_exits_2_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("[control]\nrate_hz = 0\n")
    done = subprocess.run([sys.executable, "-m", "feeder", "daemon", "--config", str(path)],
                          capture_output=True, text=True, timeout=60, cwd=tmp_path,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "rate_hz" in done.stderr
