"""Bad input on the `feeder` command line (issue #12): named regressions and a hypothesis fuzz.

Every case runs ``feeder.cli.main`` in-process and asserts the CLI contract: exit code 2 with
one line on stderr naming the option or file for bad input (0 or 1 otherwise), no traceback,
no Python warning and no log record at WARNING or above, within a per-case time limit.
Sub-commands that talk to the daemon or run long (daemon, demo, sweep, move, status, ...,
figures, adhesion fit, surface) are not fuzzed here.  ``--runslow`` runs a longer fuzz.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import signal
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from feeder.cli import main
from feeder.errors import InputError
from feeder.files import write_text

REPO = Path(__file__).resolve().parents[1]
WAVEFORM = str(REPO / "waveforms" / "paper-100hz-200vpp.toml")
CURVE = str(REPO / "examples" / "force_curves" / "flat_300x300_1.csv")
CASE_LIMIT_S = 20


class CaseTimeout(Exception):
    """A CLI case ran past :data:`CASE_LIMIT_S`."""


@dataclass
class Ran:
    code: int | str | None
    out: str
    err: str
    warned: list[str] = field(default_factory=list)


class _Records(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(f"log {record.levelname}: {record.getMessage()}")


@contextlib.contextmanager
def _time_limit(seconds: int) -> Iterator[None]:
    def expired(signum: int, frame: FrameType | None) -> None:
        raise CaseTimeout(f"over {seconds} s")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def run_cli(argv: list[str], limit_s: int = CASE_LIMIT_S) -> Ran:
    """``feeder ARGV`` in-process: exit code, stdout, stderr, warnings and log records."""
    out, err, records = io.StringIO(), io.StringIO(), _Records()
    root = logging.getLogger()
    root.addHandler(records)
    try:
        with (
            warnings.catch_warnings(record=True) as caught,
            contextlib.redirect_stdout(out),
            contextlib.redirect_stderr(err),
            _time_limit(limit_s),
        ):
            warnings.simplefilter("always")
            try:
                code: int | str | None = main(argv)
            except SystemExit as exit_:
                code = exit_.code
    finally:
        root.removeHandler(records)
    warned = [f"{w.category.__name__}: {w.message}" for w in caught] + records.messages
    return Ran(code, out.getvalue(), err.getvalue(), warned)


def assert_clean(ran: Ran, argv: list[str]) -> None:
    """Exit 0/1/2, no traceback or warning; exit 2 is one line."""
    assert ran.code in (0, 1, 2), (argv, ran.code, ran.err[-2000:])
    assert "Traceback" not in ran.err and "Warning" not in ran.err, (argv, ran.err[-2000:])
    assert not ran.warned, (argv, ran.warned)
    if ran.code == 2:
        assert len(ran.err.strip().splitlines()) == 1, (argv, ran.err)


def assert_refused(argv: list[str], *named: str) -> Ran:
    """Exit 2, one clean line on stderr naming each of ``named``."""
    ran = run_cli(argv)
    assert_clean(ran, argv)
    assert ran.code == 2, (argv, ran.code, ran.out[-500:], ran.err)
    for name in named:
        assert name in ran.err, (argv, name, ran.err)
    return ran


@pytest.fixture(scope="module")
def image(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A 64×64 PNG with one bright square."""
    import cv2

    pixels = np.zeros((64, 64), np.uint8)
    pixels[20:40, 20:40] = 255
    path = tmp_path_factory.mktemp("img") / "part.png"
    cv2.imwrite(str(path), pixels)
    return str(path)


# ---------------------------------------------------------------- named regressions


@pytest.mark.parametrize("part", ["0.001x1x1", "1e9x1x1", "200000x300x50", "300x300x0.5",
                                  "300x300x20000", "0x300x50", "300x300"])  # fmt: skip
def test_part_outside_the_accepted_ranges_is_refused(part: str) -> None:
    assert_refused(["contact", "--part", part, "--placements", "0"], "--part")


def test_part_ranges_are_stated_in_help() -> None:
    ran = run_cli(["contact", "--help"])
    assert ran.code == 0 and "1 µm–100000 µm" in ran.out and "thickness 1 µm–10000 µm" in ran.out


def test_part_ranges_accept_their_ends() -> None:
    for part in ("1x1x1", "100000x100000x10000"):
        ran = run_cli(["contact", "--part", part, "--placements", "0", "--json"])
        assert_clean(ran, [part])
        assert ran.code == 0, ran.err


def test_huge_integer_in_a_toml_file_names_the_file(tmp_path: Path) -> None:
    surface = tmp_path / "surface.toml"
    surface.write_text("[surface]\nsigma_m = " + "9" * 400 + "\n")
    assert_refused(["contact", "--part", "300x300x50", "--surface", str(surface)], str(surface))
    waveform = tmp_path / "waveform.toml"
    waveform.write_text(
        Path(WAVEFORM).read_text().replace("frequency_hz = 100.0", "frequency_hz = " + "9" * 400)
    )
    assert_refused(["waveform", "show", str(waveform)], str(waveform))


def test_tiny_pixel_size_is_refused(image: str) -> None:
    assert_refused(["vision", "locate", image, "--pixel-size", "1e-300"], "--pixel-size")
    assert_refused(["surface", image, "--pixel-size", "1e-300"], "--pixel-size")


@pytest.mark.parametrize(("argv", "message"), [
    (["tau", "--part", "300x300x50", "--force", "-1e-6"], "--force: must be a positive force"),
    (["surface", CURVE, "--pixel-size", "-2e-9"], "--pixel-size: must be from 1e-12"),
    (["contact", "--part", "300x300x50", "--tau", "-1e9"], "--tau: must be a positive number"),
    (["plan", "--part", "300x300x50", "--distance-m", "-2e0"], "--distance-m: must be from -1 m to 1 m"),
])  # fmt: skip
def test_negative_values_in_scientific_notation_reach_their_checks(argv: list[str], message: str) -> None:
    assert "expected one argument" not in assert_refused(argv, message).err


def test_plan_takes_a_backward_distance_in_scientific_notation() -> None:
    argv = ["plan", "--part", "300x300x50", "--distance-m", "-1e-4"]
    ran = run_cli(argv)
    assert_clean(ran, argv)
    assert ran.code == 0 and "move -100 µm" in ran.out and "backward" in ran.out, ran.err


def test_negative_seed_is_refused() -> None:
    assert_refused(["simulate", "--part", "500x500x50", "--waveform", WAVEFORM, "--scatter", "0.1",
                    "--seed", "-1"], "--seed")  # fmt: skip


@pytest.mark.parametrize("argv", [
    ["plan", "--part", "300x300x50", "--distance-m", "1e-4", "--out"],
    ["waveform", "export", WAVEFORM, "--format", "csv", "--out"],
    ["waveform", "show", WAVEFORM, "--plot"],
    ["simulate", "--part", "500x500x50", "--waveform", WAVEFORM, "--periods", "2", "--plot"],
    ["friction", CURVE, "--plot"],
])  # fmt: skip
def test_out_into_a_missing_directory_is_refused(argv: list[str], tmp_path: Path) -> None:
    target = tmp_path / "missing" / "file.out"
    assert_refused([*argv, str(target)], argv[-1], "no such directory")
    assert not (tmp_path / "missing").exists()


def test_out_onto_a_directory_writes_nothing(tmp_path: Path) -> None:
    (tmp_path / "dir").mkdir()
    argv = ["waveform", "export", WAVEFORM, "--format", "csv", "--out", str(tmp_path / "dir")]
    assert_refused(argv, "--out", "is a directory")
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["dir"]


@pytest.mark.parametrize("flag", ["--plot", "--out"])
def test_a_special_file_is_never_replaced_by_an_output(flag: str, tmp_path: Path) -> None:
    """`--plot /dev/zero` once renamed a PNG over the device; now refused, the FIFO here untouched."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    argv = (
        ["waveform", "export", WAVEFORM, "--format", "csv"]
        if flag == "--out"
        else ["waveform", "show", WAVEFORM]
    )
    assert_refused([*argv, flag, str(fifo)], flag, "not a regular file")
    assert fifo.is_fifo()


def test_the_writers_refuse_to_replace_a_special_file(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="fifo: cannot write: exists and is not a regular file"):
        write_text(fifo, "x")
    assert fifo.is_fifo() and sorted(p.name for p in tmp_path.iterdir()) == ["fifo"]


def test_a_failed_atomic_write_names_the_file_and_leaves_nothing(tmp_path: Path) -> None:
    (tmp_path / "taken").mkdir()
    with pytest.raises(InputError, match="taken: cannot write"):
        write_text(tmp_path / "taken", "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"]


@pytest.mark.parametrize("argv", [
    ["contact", "--part", "300x300x50", "--surface", "/dev/zero"],
    ["simulate", "--part", "500x500x50", "--waveform", "/dev/zero"],
    ["waveform", "show", "/dev/zero"],
    ["friction", "/dev/zero"],
    ["tau", "--part", "300x300x50", "--force", "/dev/zero"],
    ["surface", "/dev/zero"],
    ["vision", "locate", "/dev/zero"],
])  # fmt: skip
def test_a_device_instead_of_a_file_is_refused(argv: list[str]) -> None:
    assert_refused(argv, "/dev/zero")


def test_calibration_json_from_a_device_is_refused(image: str) -> None:
    assert_refused(["vision", "locate", image, "--calibration", "/dev/zero"], "--calibration")


def test_singular_fit_is_one_line(tmp_path: Path) -> None:
    """Axis moves whose images did not move: the least-squares fit is singular (was ZeroDivisionError)."""
    import cv2

    from firmware_sim.camera_render import CameraModel, FrameRenderer, PartInImage

    frame = FrameRenderer(CameraModel().with_noise(0.02), seed=4).render(
        [PartInImage(530.0, 490.0, 0.3, 250.0, 250.0)]
    )
    still = str(tmp_path / "still.png")
    cv2.imwrite(still, frame)
    argv = ["vision", "calibrate", "--part", "300x300x50", "--x-move", "100um", still, still,
            "--y-move", "100um", still, still]  # fmt: skip
    ran = assert_refused(argv, "moves", "singular", "--x-move")
    assert "Traceback" not in ran.err


def test_points_beyond_the_budget_are_refused_up_front() -> None:
    base = ["waveform", "export", WAVEFORM, "--format", "csv", "--points"]
    assert_refused([*base, "1000000000"], "--points")
    assert_refused([*base, "9" * 400], "--points")


def test_periods_beyond_the_limit_and_the_budget_are_refused_up_front() -> None:
    base = ["simulate", "--part", "500x500x50", "--waveform", WAVEFORM, "--json", "--periods"]
    assert_refused([*base, "1000001"], "--periods")
    ran = assert_refused([*base, "1000000"], "--periods", "2 GiB memory budget")
    assert "GiB" in ran.err


def test_placements_beyond_the_budget_are_refused_up_front() -> None:
    assert_refused(["contact", "--part", "300x300x50", "--placements", "1000000"],
                   "--placements", "2 GiB memory budget")  # fmt: skip


@pytest.mark.parametrize("argv, option", [
    (["plan", "--part", "300x300x50", "--distance-m", "1e-4", "--max-voltage-v", "1e300"],
     "--max-voltage-v"),
    (["friction", CURVE, "--stiffness", "1e300"], "--stiffness"),
    (["adhesion", "sphere", "--radius", "1e-6", "--modulus", "1e11", "--adhesion-work", "0.1",
      "--tabor", "1e-300"], "--tabor"),
    (["adhesion", "sphere", "--radius", "1e300", "--modulus", "1e11", "--adhesion-work", "0.1"],
     "--radius"),
    (["adhesion", "sphere", "--radius", "1e-6", "--modulus", "1e-300", "--adhesion-work", "0.1"],
     "--modulus"),
    (["adhesion", "sphere", "--radius", "1e-6", "--modulus", "1e11", "--adhesion-work", "0.1",
      "--range", "1e300"], "--range"),
    (["adhesion", "sphere", "--radius", "1e-6", "--modulus", "1e11", "--adhesion-work", "0.1",
      "--load", "1e300"], "--load"),
    (["contact", "--part", "300x300x50", "--adhesion-work", "1e-300"], "--adhesion-work"),
    (["surface", "--cutoff-wavelength", "1e300", CURVE], "--cutoff-wavelength"),
])  # fmt: skip
def test_values_that_overflowed_or_warned_are_refused(argv: list[str], option: str) -> None:
    assert_refused(argv, option)


def test_too_long_file_name_is_one_line(tmp_path: Path) -> None:
    assert_refused(["waveform", "show", "9" * 400], "9" * 30)
    assert_refused(["waveform", "show", WAVEFORM, "--plot", str(tmp_path / ("9" * 400))], "--plot")


# ---------------------------------------------------------------- fuzz


def _bases(image: str, tmp: Path) -> dict[str, tuple[list[str], list[str]]]:
    """Sub-command → (a valid, fast invocation, options to mutate; POS = its positional file)."""
    return {
        "contact": (["contact", "--part", "300x300x50", "--placements", "0", "--json"],
                    ["--part", "--support", "--surface", "--density", "--adhesion-work", "--tau",
                     "--tau-adhesion-work", "--tau-band", "--placements"]),
        "sphere": (["adhesion", "sphere", "--radius", "1e-6", "--modulus", "1e11", "--adhesion-work",
                    "0.1", "--load", "1e-6", "--json"],
                   ["--radius", "--modulus", "--adhesion-work", "--tabor", "--range", "--load",
                    "--max-load", "--plot", "--model"]),
        "friction": (["friction", CURVE, "--json"],
                     ["POS", "--cantilever", "--stiffness", "--baseline-fraction", "--plot"]),
        "tau": (["tau", "--part", "300x300x50", "--force", "1e-4", "--json"],
                ["--part", "--force", "--real-area", "--area-band", "--adhesion-work-band", "--stiffness",
                 "--baseline-fraction", "--support", "--density", "--tau"]),
        "show": (["waveform", "show", WAVEFORM, "--json"], ["POS", "--plot"]),
        "export": (["waveform", "export", WAVEFORM, "--format", "csv", "--out", str(tmp / "w.csv"), "--json"],
                   ["POS", "--points", "--axis", "--out", "--format"]),
        "simulate": (["simulate", "--part", "500x500x50", "--periods", "3", "--waveform", WAVEFORM, "--json"],
                     ["--part", "--periods", "--scatter", "--seed", "--waveform", "--kinetic-ratio",
                      "--plot", "--tau", "--pose", "--density"]),
        "ideal": (["simulate", "--part", "500x500x50", "--periods", "3", "--ideal", "--stroke-m", "1e-6",
                   "--frequency-hz", "100", "--json"],
                  ["--part", "--periods", "--stroke-m", "--frequency-hz", "--flyback-s", "--pose",
                   "--map-extent-m", "--map-points", "--axis", "--stroke-rad", "--map", "--flyback-shape"]),
        "plan": (["plan", "--part", "300x300x50", "--distance-m", "1e-4", "--json"],
                 ["--part", "--distance-m", "--margin", "--frequency-hz", "--amplifier", "--max-voltage-v",
                  "--current-limit-a", "--max-frequency-hz", "--out", "--kinetic-ratio", "--tau-band"]),
        "locate": (["vision", "locate", image, "--json"],
                   ["POS", "--pixel-size", "--part", "--calibration", "--plot", "--polarity"]),
    }  # fmt: skip


HOSTILE = ["0", "-0", "-1", "1e-300", "1e300", "nan", "NaN", "inf", "-inf", "", " ", "9" * 400,
           "-" + "9" * 400, "1e999", "0x10", "ü∂€", "300x300x50", "0.001x1x1", "1e9x1x1",
           "/dev/zero", "/dev/null", "/nonexistent/dir/file.png", "/", ".", "1,2,3", "nan,0,0",
           "1000000", "1000000000", "2147483648", "1e-9", "1e6", "-1e-6"]  # fmt: skip

_values = st.one_of(
    st.sampled_from(HOSTILE),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(10**400), max_value=10**400).map(str),
    st.text(st.characters(exclude_categories=["Cs"], exclude_characters="\x00"), max_size=12),
)


def _mutated(base: list[str], option: str, value: str) -> list[str]:
    argv = list(base)
    if option == "POS":
        argv[1 if argv[0] == "friction" else 2] = value  # friction CURVE; waveform show F; vision locate F
    elif option in argv:
        i = argv.index(option)
        argv[i : i + 2] = [f"{option}={value}"]
    else:
        argv.append(f"{option}={value}")
    return argv


def _fuzz(examples: int) -> object:
    @settings(
        max_examples=examples,
        deadline=None,
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    )
    @given(data=st.data())
    def run(data: st.DataObject, image: str, tmp_path: Path) -> None:
        os.chdir(tmp_path)  # a relative --plot or --out lands here
        bases = _bases(image, tmp_path)
        base, options = bases[data.draw(st.sampled_from(sorted(bases)), label="command")]
        argv = base
        for _ in range(data.draw(st.integers(1, 2), label="mutations")):
            argv = _mutated(argv, data.draw(st.sampled_from(options)), data.draw(_values))
        try:
            assert_clean(run_cli(argv), argv)
        finally:
            os.chdir(REPO)

    return run  # fmt: skip


test_fuzz_cli_arguments = _fuzz(150)
test_fuzz_cli_arguments_long = pytest.mark.slow(_fuzz(3000))
