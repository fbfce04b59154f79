"""Configuration keys of a real installation: the ANC300's serial rate and paths next to the file."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder.daemon.config import AmplifierConfig
from feeder.daemon.config_file import load_config
from feeder.errors import InputError
from feeder.surface.parameters import DEFAULT_SURFACE, load_surface

ROOT = Path(__file__).resolve().parents[1]


def test_the_serial_rate_defaults_to_the_anc300s_and_is_configurable(tmp_path: Path) -> None:
    path = tmp_path / "feeder.toml"
    path.write_text('[amplifier]\nport = "/dev/ttyUSB0"\n')
    assert load_config(path).amplifier.baudrate == 38400 == AmplifierConfig().baudrate
    path.write_text('[amplifier]\nport = "/dev/ttyUSB0"\nbaudrate = 9600\n')
    assert load_config(path).amplifier.baudrate == 9600


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ("0", "amplifier.baudrate = 0 is outside [300, 4e+06]"),
        ("10000000", "amplifier.baudrate = 10000000 is outside"),
        ("9600.0", "amplifier.baudrate must be an integer, got float"),
        ('"fast"', "amplifier.baudrate must be an integer, got str"),
        ("true", "amplifier.baudrate must be an integer, got bool"),
    ],
)
def test_a_bad_serial_rate_is_refused_by_name_in_one_line(tmp_path: Path, value: str, words: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(f"[amplifier]\nbaudrate = {value}\n")
    with pytest.raises(InputError) as err:
        load_config(path)
    assert words in str(err.value) and str(path) in str(err.value)
    assert "\n" not in str(err.value)


def test_a_relative_surface_is_found_next_to_the_file_whatever_the_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = tmp_path / "etc" / "feeder"
    folder.mkdir(parents=True)
    DEFAULT_SURFACE.write_toml(folder / "surface.toml")
    (folder / "feeder.toml").write_text('[part]\nsurface = "surface.toml"\n')
    elsewhere = tmp_path / "elsewhere"  # systemd starts the daemon in /
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    config = load_config(folder / "feeder.toml")
    assert config.surface_path == folder / "surface.toml"
    assert load_surface(config.surface_path) == DEFAULT_SURFACE
    # an absolute path stays as it is; a relative configuration path still works from its folder
    (folder / "feeder.toml").write_text(f'[part]\nsurface = "{folder / "surface.toml"}"\n')
    assert load_config(folder / "feeder.toml").surface_path == folder / "surface.toml"
    monkeypatch.chdir(tmp_path)
    (folder / "feeder.toml").write_text('[part]\nsurface = "surface.toml"\n')
    assert load_config(Path("etc/feeder/feeder.toml")).surface_path == folder / "surface.toml"


def test_relative_state_paths_are_next_to_the_file_whatever_the_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = tmp_path / "etc" / "feeder"
    folder.mkdir(parents=True)
    (folder / "feeder.toml").write_text('[state]\ndir = "state"\nsocket = "run/f.sock"\n')
    monkeypatch.chdir(tmp_path)
    config = load_config(Path("etc/feeder/feeder.toml"))
    assert config.state_dir == folder / "state" and config.socket_path == folder / "run" / "f.sock"
    (folder / "feeder.toml").write_text('[state]\ndir = "~/st"\n')
    assert load_config(folder / "feeder.toml").state_dir == Path("~/st").expanduser()
