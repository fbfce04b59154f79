"""A plane located by the camera moves parts only where the camera sees them (the configuration's travel)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from feeder.daemon.config import PLANE_TRAVEL_M, VIEW_MARGIN_PX, CameraConfig, DaemonConfig, embedded_plane
from feeder.daemon.config_file import load_config
from feeder.daemon.jobs import LoopSettings
from feeder.daemon.links import DriverLinks
from feeder.errors import InputError
from feeder.parts import Part
from feeder.vision.calibration import CameraCalibration

PLANE = '[plate]\naxes = ["x", "y", "theta"]\nparts = "0,0,0;0.36e-3,0,0"\n'
"""The review's configuration: the plane with two parts and the default camera (2048 px at 2.7 µm)."""


def travel(config: DaemonConfig) -> tuple[float, float, float, float]:
    loop = config.loop
    return loop.min_position_m, loop.max_position_m, loop.min_y_m, loop.max_y_m


def load(tmp_path: Path, text: str) -> DaemonConfig:
    path = tmp_path / "plane.toml"
    path.write_text(text)
    return load_config(path)


def test_a_planes_default_travel_is_what_the_camera_sees_of_the_whole_part(tmp_path: Path) -> None:
    """2048 px at 2.7 µm see ±2.765 mm; a 300 µm square's centre may go to within its
    half-diagonal (212 µm) and 10 px (27 µm) of the image's edge: ±2.526 mm, not the loop's
    ±5 mm in x and ±10 mm in y (the review's move to x = −4 mm lost the part)."""
    half = 1024 * 2.7e-6 - 0.5 * math.hypot(300e-6, 300e-6) - VIEW_MARGIN_PX * 2.7e-6
    assert travel(load(tmp_path, PLANE)) == pytest.approx((-half, half, -half, half), abs=1e-12)
    assert half == pytest.approx(2.5257e-3, abs=1e-7) and -half > -4e-3
    wide = load(
        tmp_path,
        PLANE
        + '[part]\nsize = "500x300x50"\n[camera]\nwidth_px = 1024\nheight_px = 600\npixel_size_m = 5e-6\n',
    )
    margin = 0.5 * math.hypot(500e-6, 300e-6) + VIEW_MARGIN_PX * 5e-6
    x, y = 512 * 5e-6 - margin, 300 * 5e-6 - margin
    assert travel(wide) == pytest.approx((-x, x, -y, y), abs=1e-12)
    narrowed = load(tmp_path, PLANE + "[control]\nmin_position_m = -1e-3\nmax_y_m = 2.5e-3\n")
    assert travel(narrowed) == pytest.approx((-1e-3, half, -half, 2.5e-3), abs=1e-12)  # within: kept
    # a position stream measures the part itself: no camera, the loop's travel
    streamed = load(tmp_path, PLANE + '[sensor]\naddress = "socket://127.0.0.1:7240"\n')
    assert travel(streamed) == travel(DaemonConfig())


@pytest.mark.parametrize(
    ("control", "key"),
    [
        ("min_position_m = -4e-3", "control.min_position_m = -0.004"),  # the review's move
        ("max_position_m = 2.6e-3", "control.max_position_m = 0.0026"),
        ("min_y_m = -5e-3\nmax_y_m = 5e-3", "control.min_y_m = -0.005"),
        ("max_y_m = 2.6e-3", "control.max_y_m = 0.0026"),
    ],
)
def test_a_configured_travel_beyond_the_view_is_refused_naming_the_key(
    tmp_path: Path, control: str, key: str
) -> None:
    with pytest.raises(InputError) as err:
        load(tmp_path, f"{PLANE}[control]\n{control}\n")
    text = str(err.value)
    assert key in text and "reaches beyond the camera's view" in text and "\n" not in text
    assert "x [-0.002526, 0.002526] m, y [-0.002526, 0.002526] m" in text  # the field's limits


def test_a_camera_too_small_for_the_part_is_refused(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="the image is too small for the part"):
        load(tmp_path, PLANE + "[camera]\nwidth_px = 64\nheight_px = 64\n")


def test_the_embedded_plane_keeps_its_travel(tmp_path: Path) -> None:
    """``feeder daemon`` (and ``--plane``, the demo): ±2.4 mm, within what its camera sees."""
    embedded = (-PLANE_TRAVEL_M, PLANE_TRAVEL_M, -PLANE_TRAVEL_M, PLANE_TRAVEL_M)
    assert travel(embedded_plane(DaemonConfig())) == embedded == (-2.4e-3, 2.4e-3, -2.4e-3, 2.4e-3)
    assert travel(embedded_plane(load(tmp_path, PLANE))) == embedded
    assert min(CameraConfig().travel_m(Part.parse("300x300x50"))) > PLANE_TRAVEL_M
    assert travel(load_config(None)) == (-5e-3, 5e-3, -10e-3, 10e-3)  # one axis, no camera: unchanged


CAMERA = CameraConfig()


def centred(pixel_size_m: float = CAMERA.pixel_size_m, **turned: float | bool) -> CameraCalibration:
    """A calibration with O at the image's centre, as the configuration gives (turned: a stored one)."""
    return CameraCalibration(
        pixel_size_m, origin_x_px=(CAMERA.width_px - 1) / 2, origin_y_px=(CAMERA.height_px - 1) / 2, **turned
    )  # type: ignore[arg-type]


def square_travel(half_m: float) -> LoopSettings:
    return LoopSettings(min_position_m=-half_m, max_position_m=half_m, min_y_m=-half_m, max_y_m=half_m)


def test_the_default_travel_lies_just_within_the_configured_cameras_view() -> None:
    part = Part.parse("300x300x50")
    half_x, _ = CAMERA.travel_m(part)
    assert CAMERA.travel_outside(centred(), part, square_travel(half_x)) is None  # the edge itself
    assert CAMERA.travel_outside(centred(), part, square_travel(PLANE_TRAVEL_M)) is None
    # room for a measured calibration's error (the page's camera calibration found 2.695 µm/px,
    # O 3 px off: refused for the travel at ±2.5 mm)
    measured = CameraCalibration(
        0.97 * CAMERA.pixel_size_m, origin_x_px=1030.0, origin_y_px=1016.0, rotation_rad=0.01
    )
    assert CAMERA.travel_outside(measured, part, square_travel(PLANE_TRAVEL_M)) is None
    assert CAMERA.travel_outside(measured, part, square_travel(2.5e-3)) is not None
    beyond = CAMERA.travel_outside(centred(), part, square_travel(half_x + 1e-6))
    assert beyond is not None and "the travel scaled by 1.000 about O fits" in beyond


def test_a_stored_calibration_turned_or_finer_sees_less_of_the_travel() -> None:
    """A camera turned 0.4 rad sees the ±2.5 mm square's corners off the image; the reply says by
    how much to shrink it, and that much fits (exactly: the edge is a corner's)."""
    part = Part.parse("300x300x50")
    turned = centred(rotation_rad=0.4, mirrored=True)
    reason = CAMERA.travel_outside(turned, part, square_travel(2.5e-3))
    assert reason is not None
    assert "turned 22.9°, mirrored" in reason and "2048×2048 px image" in reason
    fits = float(reason.split("scaled by ")[1].split()[0])
    reach_m = 0.5 * math.hypot(300e-6, 300e-6) + VIEW_MARGIN_PX * 2.7e-6
    expected = (1024 * 2.7e-6 - reach_m) / (2.5e-3 * (math.cos(0.4) + math.sin(0.4)))  # a corner's reach
    assert fits == pytest.approx(expected, abs=1e-3)
    assert CAMERA.travel_outside(turned, part, square_travel(2.5e-3 * (expected - 1e-6))) is None
    assert CAMERA.travel_outside(turned, part, square_travel(2.5e-3 * (expected + 1e-3))) is not None
    assert CAMERA.travel_outside(centred(2.0e-6), part, square_travel(2.5e-3)) is not None  # finer: smaller


def test_a_planes_camera_refuses_a_travel_it_cannot_see_before_it_is_opened(tmp_path: Path) -> None:
    config = embedded_plane(DaemonConfig(state_dir=tmp_path / "state"))
    links = DriverLinks(config, "unused", "http://127.0.0.1:9/unused.mjpg")
    with pytest.raises(InputError, match=r"^travel: the travel x \[-0.0024, 0.0024\] m.*turned 22.9°"):
        links.open_sensor(centred(rotation_rad=0.4))


def test_one_axis_located_by_a_camera_keeps_x_within_its_view(tmp_path: Path) -> None:
    """Part 1's x along the axis, read by a camera: x's travel is the camera's (it was the loop's
    ±5 mm against a ±2.76 mm view); y is wherever the part lies, so its limits stay."""
    camera = '[camera]\naddress = "http://127.0.0.1:9/video.mjpg"\n'
    config = load(tmp_path, camera)
    half, _ = CAMERA.travel_m(config.part)
    assert travel(config) == pytest.approx((-half, half, LoopSettings().min_y_m, LoopSettings().max_y_m))
    with pytest.raises(InputError, match=r"control.max_position_m = 0.004 reaches beyond the camera's view"):
        load(tmp_path, camera + "[control]\nmax_position_m = 4e-3\n")
    assert (
        travel(load(tmp_path, "[control]\nmax_position_m = 4e-3\n"))[1] == 4e-3
    )  # a position stream: as set
