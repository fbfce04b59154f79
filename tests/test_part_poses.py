"""A part's pose is checked once (feeder/pose.py part_pose) wherever a user gives
one: the daemon's ``[plate] parts``, ``firmware_sim --parts``, ``feeder simulate --pose`` and
``feeder waveform design --pose``/``--radius-m``: one line naming the field, exit code 2,
nothing written."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from feeder.cli import main
from feeder.daemon.config_file import load_config
from feeder.errors import InputError
from firmware_sim.options import build_parser

PLANE = '[plate]\naxes = ["x", "y", "theta"]\nparts = "{parts}"\n'
ONE_AXIS = '[plate]\nparts = "{parts}"\n'
RANGE = "needs |X|, |Y| ≤ 0.1 m and |PSI| ≤ 2π rad (a part on the plate)"


def config(tmp_path: Path, template: str, parts: str) -> Path:
    path = tmp_path / "feeder.toml"
    path.write_text(template.format(parts=parts))
    return path


@pytest.mark.parametrize(
    ("template", "parts", "words"),
    [
        (PLANE, "1,0,0", f"plate.parts: {RANGE}, got 1,0,0"),  # the audit's part 1 m from O
        (PLANE, "0,0,50", f"plate.parts: {RANGE}, got 0,0,50"),  # ψ = 50 rad
        (ONE_AXIS, "1,0,0", f"plate.parts: {RANGE}, got 1,0,0"),  # whatever the axes
        (PLANE, "0,0,0;0,-0.2,0", f"plate.parts: part 2: {RANGE}, got 0,-0.2,0"),
        # on the plate, but where the simulator's camera does not see the part whole
        (PLANE, "0,0,0;2.6e-3,0,0", "plate.parts: part 2 at (0.0026, 0) m is out of view"),
        (PLANE, "0,-3e-3,0", "y [-0.002526, 0.002526] m"),
    ],
    ids=[
        "1 m from O",
        "50 rad",
        "one axis",
        "part 2 off the plate",
        "part 2 out of view",
        "out of view in y",
    ],
)
def test_the_daemons_parts_off_the_plate_or_out_of_view_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], template: str, parts: str, words: str
) -> None:
    """The old code started the daemon, which stayed in fault (it could not locate the part)."""
    path = config(tmp_path, template, parts)
    with pytest.raises(InputError) as err:
        load_config(path)
    assert words in str(err.value) and "\n" not in str(err.value)
    state = tmp_path / "state"
    argv = ["daemon", "--config", str(path), "--state-dir", str(state), "--socket", str(tmp_path / "s")]
    assert main(argv) == 2
    assert capsys.readouterr().err.count("\n") == 1
    assert not state.exists()  # nothing written


def test_the_daemon_keeps_parts_on_the_plate_and_in_view(tmp_path: Path) -> None:
    plane = load_config(config(tmp_path, PLANE, "0,0,0;2.5e-3,-2.5e-3,-6.28;0.36e-3,0,6.28"))
    assert plane.plate.parts == ((0, 0, 0), (2.5e-3, -2.5e-3, -6.28), (0.36e-3, 0, 6.28))
    # one axis, or hardware: where the parts start is not the simulator's to place
    assert load_config(config(tmp_path, ONE_AXIS, "0.1,-0.1,0")).plate.parts == ((0.1, -0.1, 0.0),)
    hardware = PLANE + '[amplifier]\nport = "/dev/ttyUSB0"\n'
    assert load_config(config(tmp_path, hardware, "0.05,0,0")).plate.parts == ((0.05, 0.0, 0.0),)


@pytest.mark.parametrize(
    ("parts", "words"),
    [("1,0,0", f"{RANGE}, got 1,0,0"), ("0,0,50", f"{RANGE}, got 0,0,50"), ("0,0,0;0,0,-7", "part 2: ")],
)
def test_firmware_sim_refuses_parts_off_the_plate(
    capsys: pytest.CaptureFixture[str], parts: str, words: str
) -> None:
    """The old code placed them: a part 1 m from O."""
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(["--plant", "planar", f"--parts={parts}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1
    assert err.startswith("firmware_sim: error: argument --parts: ") and words in err


def test_firmware_sim_keeps_parts_on_the_plate() -> None:
    args = build_parser().parse_args(["--plant", "planar", "--parts=0.1,-0.1,6.28;0,0,-6.28"])
    assert args.parts == "0.1,-0.1,6.28;0,0,-6.28"


@pytest.fixture
def no_design(monkeypatch: pytest.MonkeyPatch) -> None:
    """A design that gets as far as designing was accepted: fail at once (not after a search)."""

    def accepted(*_: object, **__: object) -> None:
        raise AssertionError("the pose was accepted")

    monkeypatch.setattr("feeder.axis_design.design_axis", accepted)


DESIGN = ["waveform", "design", "--part", "300x300x50", "--axis", "theta"]
SIMULATE = ["simulate", "--ideal", "--axis", "theta", "--stroke-rad", "1e-3", "--flyback-s", "3.5e-4"]


@pytest.mark.usefixtures("no_design")
@pytest.mark.parametrize("pose", ["0,0,99", "1,0,0", "0,-0.2,0", "0,0,-360.5deg"])
def test_waveform_design_refuses_the_poses_simulate_refuses(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], pose: str
) -> None:
    """The old code designed for ψ = 99 rad while ``feeder simulate --pose`` refused it."""
    out = tmp_path / "design.toml"
    answers = []
    for argv in ([*DESIGN, "--out", str(out)], SIMULATE):
        with pytest.raises(SystemExit) as exit_:
            main([*argv, f"--pose={pose}"])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and err.count("\n") == 1
        answers.append(err.split("argument --pose: ", 1)[1])
    assert answers[0] == answers[1] == f"{RANGE}, got {pose!r}\n"
    assert not out.exists()


@pytest.mark.usefixtures("no_design")
def test_waveform_design_refuses_a_radius_off_the_plate(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "design.toml"
    assert main([*DESIGN, "--radius-m", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--radius-m: {RANGE}, got R = 1 m (the pose R,0,0)" in err
    assert not out.exists()


def test_the_range_is_the_one_simulate_stated() -> None:
    """|X|, |Y| ≤ 0.1 m, |PSI| ≤ 2π (``feeder simulate --help``), the ends included."""
    from feeder.pose import part_pose, part_poses  # the one check (new)

    assert part_pose((0.1, -0.1, -2 * math.pi), "f") == (0.1, -0.1, -2 * math.pi)
    for bad in ((0.1000001, 0, 0), (0, 0, 6.2832), (math.nan, 0, 0), (0, 0)):
        with pytest.raises(InputError, match=r"^f: "):
            part_pose(bad, "f")
    assert part_poses("0,0,0;0.1,0,1", "f") == ((0, 0, 0), (0.1, 0, 1))


def test_plane_keeps_the_parts_a_one_axis_configuration_names(tmp_path: Path) -> None:
    """`feeder daemon --config FILE --plane` with only ``[plate] parts``: the old code put the
    embedded plane's one default part there instead (``--part 2`` then refused)."""
    from feeder.daemon.config import PLANE_START_POSE, embedded_plane

    named = tmp_path / "two.toml"
    named.write_text('[plate]\nparts = "-0.9e-3,0.1e-3,0;0.9e-3,-0.1e-3,0.3"\n')
    assert embedded_plane(load_config(named)).plate.parts == ((-0.9e-3, 0.1e-3, 0.0), (0.9e-3, -0.1e-3, 0.3))
    unnamed = tmp_path / "none.toml"
    unnamed.write_text("[plate]\nlever_arm_m = 1e-3\n")
    assert embedded_plane(load_config(unnamed)).plate.parts == (PLANE_START_POSE,)
