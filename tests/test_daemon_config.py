"""The daemon's TOML configuration: defaults, a full file, and one-line refusals."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from feeder.daemon.config import (
    SIM_TICK_WATCHDOG_S,
    DaemonConfig,
    default_socket_path,
    default_state_dir,
    embedded_plane,
)
from feeder.daemon.config_file import SECTIONS, load_config
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


@pytest.mark.parametrize(
    "text, words",
    [
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
        ("[part]\nsize = '300x300'", "part.size: expected LxWxT"),
        ("[part]\nsupport = 'bumpy'", "part.support: expected one of"),
        ("[part]\nsurface = 'does_not_exist.toml'", "part.surface: "),
        ("[amplifier]\nport = 5", "amplifier.port must be a string"),
        ("[amplifier]\nlimits = 5", "[amplifier.limits] must be a table"),
        ("not toml [", "not valid TOML"),
    ],
)
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
    path.write_text(
        "[part]\nsize = '200x100x50'\n[amplifier.limits]\nv_max_v = 120.0\n"
        "[simulator]\nargs = ['--seed', '9']\n"
    )
    args = simulator_args(load_config(path))
    assert args[args.index("--part") + 1] == "200x100x50"
    assert float(args[args.index("--v-max") + 1]) == 120.0
    assert args[-2:] == ["--seed", "9"]
    assert "--can" not in args
    assert "--can" in simulator_args(load_config(path).with_transport("can"))
    # the embedded line's tick watchdog is relaxed as the plane's: a loaded CI machine stalled
    # the simulator's process > 0.25 s and `feeder demo --line` ended a move "Axis in wrong mode"
    for world in (load_config(path), embedded_plane(load_config(path))):
        sim = simulator_args(world)
        assert sim.count("--watchdog-s") == 1
        assert float(sim[sim.index("--watchdog-s") + 1]) == SIM_TICK_WATCHDOG_S


@pytest.mark.parametrize(
    ("body", "words"),
    [
        ("[control]\nrate_hz = 0\n", "rate_hz"),
        ("[amplifier]\nbaudrate = 12\n", "amplifier.baudrate = 12 is outside"),
        (  # an slcan adapter opened without a bit rate floods a live bus at its stored one
            '[amplifier]\ntransport = "can"\nmodel = "firmware_sim"\n[amplifier.can]\ninterface = "slcan"\n'
            'channel = "/dev/ttyACM0"\n[sensor]\naddress = "socket://127.0.0.1:7240"\n',
            "amplifier.can.bitrate",
        ),
        (  # the plane's camera sees ±2.76 mm: a part at x = −4 mm was lost
            '[plate]\naxes = ["x", "y", "theta"]\n[control]\nmin_position_m = -4e-3\n',
            "control.min_position_m = -0.004 reaches beyond the camera's view",
        ),
    ],
)
def test_feeder_daemon_with_a_bad_config_exits_2_in_one_line(tmp_path: Path, body: str, words: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(body)
    done = subprocess.run(
        [sys.executable, "-m", "feeder", "daemon", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and words in done.stderr


def test_half_named_hardware_is_refused_naming_the_file_before_anything_is_written(tmp_path: Path) -> None:
    """The pairing was checked after the log had been opened: the state folder was left with it."""
    path = tmp_path / "half.toml"
    path.write_text('[amplifier]\nport = "/dev/ttyUSB7"\n')
    state = tmp_path / "state"
    done = subprocess.run(
        [sys.executable, "-m", "feeder", "daemon", "--config", str(path), "--state-dir", str(state)],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert f"{path}: name both the amplifier" in done.stderr
    assert not state.exists()


def test_simulator_arguments_it_refuses_are_bad_input(tmp_path: Path) -> None:
    """firmware_sim's own exit 2 (an argument it refuses) was reported as a launch failure, exit 1."""
    path = tmp_path / "sim.toml"
    path.write_text('[simulator]\nargs = ["--bogus-flag"]\n')
    done = subprocess.run(
        [sys.executable, "-m", "feeder", "daemon", "--config", str(path), "--state-dir", str(tmp_path / "s")],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert done.returncode == 2, done.stderr
    assert "firmware_sim: refused its arguments:" in done.stderr and "--bogus-flag" in done.stderr


def test_a_multiple_of_the_rated_frequency_step_narrows_it(tmp_path: Path) -> None:
    path = tmp_path / "step.toml"
    path.write_text("[amplifier.limits]\nfrequency_step_hz = 2.0\ncurrent_limit_a = 0.9\n")
    limits = load_config(path).amplifier.limits
    assert (limits.frequency_step_hz, limits.current_limit_a) == (2.0, 0.9)  # the unit's own current


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ('[amplifier]\nprot = "/dev/ttyUSB0"\n', "did you mean amplifier.port"),
        ('[amplfier]\nport = "/dev/ttyUSB0"\n', "did you mean [amplifier]"),
        (
            '[amplifier]\ntransport = "can"\n[amplifier.can]\ninterface = "slcan"\nchanel = "/dev/x"\n',
            "is 'chanel' meant to be 'channel'",
        ),
        (
            '[amplifier]\ntransport = "can"\n[amplifier.can]\nchannel = "can0"\nsupervise_host = 1\n',
            "amplifier.can.supervise_host must be true or false, got 1",
        ),
        ("[amplifier]\naxis = " + "9" * 400 + "\n", "amplifier.axis = a huge integer"),
        ("[control]\nrate_hz = " + "1" * 400 + "\n", "control.rate_hz"),
        ("[control]\nrate_hz = 1e-9\n", "control.rate_hz = 1e-09 is outside"),
        ("[control]\naverage_samples = 1000000000\n", "control.average_samples"),
        ("[sensor]\ntimeout_s = nan\n", "sensor.timeout_s must be a finite number"),
        ('[sensor]\naddress = "tcp:127.0.0.1:7240"\n', "socket://"),
        (
            '[amplifier]\nmodel = "anc300"\n[amplifier.limits]\nv_max_v = 200.0\n',
            "beyond the anc300's rating",
        ),
        ('[plate]\naxes = ["y", "x"]\n', "plate.axes must start with x"),
        ('[plate]\naxes = ["x", "z"]\n', "plate.axes must be a list of distinct axes"),
        ("[plate]\naxis_map = { x = 1, thta = 3 }\n", "did you mean plate.axis_map.theta"),
        ('[plate]\naxes = ["x", "y"]\naxis_map = { x = 2 }\n', "two axes the same number"),
        ('[plate]\nparts = "0,0"\n', "plate.parts: expected X,Y,PSI"),
        ("[control]\nmin_y_m = 1e-3\nmax_y_m = -1e-3\n", "control.min_y_m must be below"),
        ("[control]\ntolerance_rad = 2.0\n", "control.tolerance_rad = 2 is outside"),
        (  # refused only once the daemon had started, leaving a database behind
            '[plate]\naxes = ["x", "y", "theta"]\naxis_map = { x = 1, y = 2, theta = 99 }\n',
            "plate.axis_map.theta = 99 is outside [1, 7]",
        ),
        (
            '[amplifier]\ntransport = "can"\n[amplifier.can]\nnode_id = 126\nhost_id = 1\n'
            '[plate]\naxes = ["x", "y", "theta"]\n',
            "amplifier.can.node_id = 126: the plate's axes need nodes 126..128, beyond CANopen's 127",
        ),
        # an empty path was the configuration's own folder; an empty port, a file named ''
        ('[state]\ndir = ""\n', "state.dir is empty"),
        ('[state]\nsocket = " "\n', "state.socket is empty"),
        ('[amplifier]\nport = ""\n', "amplifier.port is empty"),
        ('[camera]\naddress = ""\n', "camera.address is empty"),
        (  # the camera was ignored without a word
            '[sensor]\naddress = "socket://127.0.0.1:7240"\n[camera]\naddress = "0"\n',
            "sensor.address and camera.address both name the sensor",
        ),
        # an ANC300 sets whole hertz: 0 ("any frequency") or a fraction is not what it can do
        ("[amplifier.limits]\nfrequency_step_hz = 0.0\n", "steps of 1 Hz"),
        ("[amplifier.limits]\nfrequency_step_hz = 2.5\n", "frequency_step_hz: 2.5 Hz"),
    ],
)
def test_misspelt_or_out_of_range_keys_are_refused_by_name(tmp_path: Path, text: str, words: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        load_config(path)
    assert words in str(err.value)
    assert "\n" not in str(err.value)


def test_the_plate_section_drives_three_axes(tmp_path: Path) -> None:
    path = tmp_path / "plane.toml"
    path.write_text(
        '[plate]\naxes = ["x", "y", "theta"]\naxis_map = { theta = 4 }\nparts = "1e-3,0,0.5;-1e-3,2e-4,0"\n'
        "[control]\nmin_y_m = -2.5e-3\nmax_y_m = 2.5e-3\ntolerance_rad = 1e-3\n"
    )
    config = load_config(path)
    assert config.plate.planar and config.plate.axes == ("x", "y", "theta")
    assert config.plate.axis_map == {"x": 1, "y": 2, "theta": 4}
    assert config.plate.parts == ((1e-3, 0.0, 0.5), (-1e-3, 2e-4, 0.0))
    assert (config.loop.min_y_m, config.loop.max_y_m, config.loop.tolerance_rad) == (-2.5e-3, 2.5e-3, 1e-3)
    assert not DaemonConfig().plate.planar  # the one-axis default until a plate is configured


def test_a_device_is_not_read_as_a_configuration() -> None:
    with pytest.raises(InputError, match="/dev/zero: not a regular file"):
        load_config(Path("/dev/zero"))


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return (
            "nan"
            if value != value
            else ("inf" if value == math.inf else "-inf" if value == -math.inf else repr(value))
        )
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, int):
        return str(value)
    return json.dumps(value)


def _toml(doc: dict[str, dict[str, Any]]) -> str:
    """A TOML document of tables of scalars (a wrong value is the loader's to refuse)."""
    return "".join(
        f"[{name}]\n" + "".join(f"{k} = {_toml_value(v)}\n" for k, v in table.items())
        for name, table in doc.items()
    )


_SCALARS = st.one_of(
    st.integers(min_value=-(10**500), max_value=10**500),
    st.floats(),
    st.text(max_size=12),
    st.booleans(),
    st.lists(st.integers(), max_size=3),
)


@given(
    st.dictionaries(
        st.sampled_from([*SECTIONS, "amplifer", "x"]),
        st.dictionaries(
            st.sampled_from(
                sorted({k for keys in SECTIONS.values() for k in keys} | {"chanel", "interface", "v_max_v"})
            ),
            _SCALARS,
            max_size=6,
        ),
        max_size=4,
    )
)
@settings(max_examples=300, deadline=1000, suppress_health_check=[HealthCheck.too_slow])
def test_fuzzed_configurations_load_or_fail_in_one_line(doc: dict[str, Any]) -> None:
    """Any document of the schema's shape with any values: a config or an InputError."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fuzz.toml"
        path.write_text(_toml(doc), encoding="utf-8")
        try:
            config = load_config(path)
        except InputError as err:
            assert "\n" not in str(err)
        else:
            assert isinstance(config, DaemonConfig)


@pytest.mark.parametrize("doc", ["docs/daemon.md", "docs/canopen.md", "docs/console.md"])
def test_every_configuration_in_the_docs_loads(tmp_path: Path, doc: str) -> None:
    """docs/canopen.md's example was refused (a CAN drive must name its model)."""
    (tmp_path / "surface.toml").write_text("")  # the one file an example names beside itself
    blocks = re.findall(r"```toml\n(.*?)```", (ROOT / doc).read_text(), re.S)
    assert blocks
    for k, block in enumerate(blocks):
        path = tmp_path / f"example{k}.toml"
        path.write_text(block)
        load_config(path)


def test_a_relative_eds_path_is_the_configurations_folder_s_wherever_the_daemon_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """It was kept relative to the working directory, and re-read there at every (re)connect."""
    from importlib import resources

    folder = tmp_path / "rig"
    folder.mkdir()
    packaged = resources.files("feeder.protocol").joinpath("feeder_amplifier.eds").read_bytes()
    (folder / "mine.eds").write_bytes(packaged)
    (folder / "feeder.toml").write_text('[amplifier]\ntransport = "can"\n[amplifier.can]\neds = "mine.eds"\n')
    monkeypatch.chdir(tmp_path)
    eds = load_config(Path("rig/feeder.toml")).amplifier.can["eds"]
    assert Path(eds).is_absolute() and Path(eds) == folder / "mine.eds"
    monkeypatch.chdir(folder.parent.parent)
    assert Path(eds).is_file()
