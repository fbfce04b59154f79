"""Camera calibration: pure functions against known transforms, and `feeder vision` end to end."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from feeder.cli import main
from feeder.daemon.store import Store
from feeder.errors import InputError
from feeder.vision.calibration import (
    CameraCalibration,
    axes_from_moves,
    pixel_size_from_part,
    rotation_centre,
)
from firmware_sim.camera_render import CameraModel, FrameRenderer, PartInImage

TRUE = CameraCalibration(
    pixel_size_m=1.2e-6, rotation_rad=0.3, mirrored=True, origin_x_px=530.5, origin_y_px=490.25
)


def test_transform_round_trip_and_angles() -> None:
    x, y = TRUE.to_image(40e-6, -25e-6)
    assert TRUE.to_plate(x, y) == pytest.approx((40e-6, -25e-6), abs=1e-15)
    assert math.hypot(x - TRUE.origin_x_px, y - TRUE.origin_y_px) == pytest.approx(math.hypot(40, 25) / 1.2)
    assert TRUE.angle_to_plate(TRUE.angle_to_image(0.7)) == pytest.approx(0.7)
    # a part's side along plate +x appears along the image direction of plate +x
    ex = np.subtract(TRUE.to_image(1e-6, 0), TRUE.to_image(0, 0))
    assert math.atan2(ex[1], ex[0]) == pytest.approx(TRUE.angle_to_image(0.0))


def test_axes_from_moves_recovers_scale_rotation_and_mirroring() -> None:
    rng = np.random.default_rng(0)
    plate = np.array([[50e-6, 0], [-30e-6, 0], [0, 40e-6], [0, -60e-6]])
    image = np.array([np.subtract(TRUE.to_image(*p), TRUE.to_image(0, 0)) for p in plate])
    fit = axes_from_moves(plate, image + rng.normal(0, 0.02, image.shape))
    assert fit.pixel_size_m == pytest.approx(1.2e-6, rel=1e-3)
    assert fit.rotation_rad == pytest.approx(0.3, abs=1e-3)
    assert fit.mirrored and fit.residual_px < 0.05 and fit.anisotropy < 2e-3
    with pytest.raises(InputError, match="both axes"):
        axes_from_moves(plate[:2], image[:2])


def test_rotation_centre_from_turns() -> None:
    turns = np.radians([5.0, -8.0, 12.0])
    before = np.array([TRUE.to_image(100e-6, 20e-6), TRUE.to_image(-50e-6, 70e-6), TRUE.to_image(0, -90e-6)])
    after = []
    for (x, y), turn in zip([(100e-6, 20e-6), (-50e-6, 70e-6), (0, -90e-6)], turns, strict=True):
        c, s = math.cos(turn), math.sin(turn)
        after.append(TRUE.to_image(c * x - s * y, s * x + c * y))
    ox, oy, residual = rotation_centre(before, np.array(after), turns, mirrored=True)
    assert (ox, oy) == pytest.approx((TRUE.origin_x_px, TRUE.origin_y_px), abs=1e-6)
    assert residual < 1e-6
    assert pixel_size_from_part(250.0, 125.0, 300e-6, 150e-6) == pytest.approx(1.2e-6)


def _write(path: Path, renderer: FrameRenderer, x_m: float, y_m: float, psi: float = 0.0) -> str:
    x, y = TRUE.to_image(x_m, y_m)
    size = 300e-6 / TRUE.pixel_size_m
    cv2.imwrite(str(path), renderer.render([PartInImage(x, y, TRUE.angle_to_image(psi), size, size)]))
    return str(path)


def test_calibrate_cli_from_rendered_images(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    renderer = FrameRenderer(CameraModel().with_noise(0.02), seed=4)

    def image(name: str, x: float, y: float, psi: float = 0.0) -> str:
        return _write(tmp_path / f"{name}.png", renderer, x, y, psi)

    # a turn about O moves a part at (x, y) to R(θ)(x, y)
    x0, y0, turn = 80e-6, -40e-6, math.radians(10)
    xt, yt = math.cos(turn) * x0 - math.sin(turn) * y0, math.sin(turn) * x0 + math.cos(turn) * y0
    out = tmp_path / "camera.json"
    argv = [
        "vision",
        "calibrate",
        "--part",
        "300x300x50",
        "--image",
        image("ref", 0, 0),
        "--x-move",
        "100um",
        image("x0", -50e-6, 0),
        image("x1", 50e-6, 0),
        "--y-move",
        "0.08mm",
        image("y0", 0, -40e-6),
        image("y1", 0, 40e-6),
        "--theta-move",
        "10deg",
        image("t0", x0, y0),
        image("t1", xt, yt, turn),
        "--out",
        str(out),
        "--save-state",
        "--state-dir",
        str(tmp_path / "state"),
        "--json",
    ]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    # stored with the step calibration, in the daemon's SQLite state
    store = Store(tmp_path / "state" / "feeder.sqlite")
    try:
        stored = store.camera_calibration()
    finally:
        store.close()
    assert stored is not None and stored["pixel_size_m"] == report["pixel_size_m"]
    assert stored["origin_x_px"] == report["origin_x_px"]
    assert "note" not in report  # written and stored: nothing to warn about
    assert main([*argv[: argv.index("--out")], "--json"]) == 0
    assert "--save-state" in json.loads(capsys.readouterr().out)["note"]  # printed only: how to keep it
    assert report["pixel_size_from_part_m"] == pytest.approx(1.2e-6, rel=5e-4)
    assert report["pixel_size_m"] == pytest.approx(1.2e-6, rel=5e-4)
    assert report["rotation_rad"] == pytest.approx(0.3, abs=2e-3) and report["mirrored"] is True
    assert report["origin_x_px"] == pytest.approx(TRUE.origin_x_px, abs=0.3)
    assert report["origin_y_px"] == pytest.approx(TRUE.origin_y_px, abs=0.3)
    # locate with that calibration gives plate poses
    assert (
        main(
            [
                "vision",
                "locate",
                image("check", 30e-6, 20e-6, 0.2),
                "--calibration",
                str(out),
                "--part",
                "300x300x50",
                "--json",
            ]
        )
        == 0
    )
    (part,) = json.loads(capsys.readouterr().out)["parts"]
    assert part["plate_x_m"] == pytest.approx(30e-6, abs=0.5e-6)
    assert part["plate_y_m"] == pytest.approx(20e-6, abs=0.5e-6)
    assert (part["plate_psi_rad"] - 0.2 + math.pi / 4) % (math.pi / 2) - math.pi / 4 == pytest.approx(
        0, abs=2e-3
    )


def test_calibrate_refuses_to_write_over_its_own_images(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The CLI audit: ``--out x0.png`` replaced the before-image of ``--x-move`` with the
    calibration's JSON (exit 0): the move's images are plain text to argparse, and the check
    saw only path-typed arguments."""
    renderer = FrameRenderer(CameraModel().with_noise(0.02), seed=4)
    images = [_write(tmp_path / f"{n}.png", renderer, x, y) for n, x, y in
              (("x0", -50e-6, 0), ("x1", 50e-6, 0), ("y0", 0, -40e-6), ("y1", 0, 40e-6))]  # fmt: skip
    before = Path(images[0]).read_bytes()
    argv = ["vision", "calibrate", "--x-move", "100um", *images[:2], "--y-move", "80um", *images[2:]]
    assert main([*argv, "--out", images[0]]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out" in err and "read by this command" in err
    assert Path(images[0]).read_bytes() == before


def test_a_calibration_without_turns_locates_about_the_image_centre(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The CLI audit: `vision calibrate --x-move … --y-move … --out camera.json` (exit 0), then
    `vision locate --calibration camera.json` refused the file ("no 'origin_x_px'") although
    docs/vision.md says locate reads it.  Without θ turns O is the image centre, as the daemon's."""
    renderer = FrameRenderer(CameraModel().with_noise(0.02), seed=4)
    images = [_write(tmp_path / f"{n}.png", renderer, x, y) for n, x, y in
              (("x0", -50e-6, 0), ("x1", 50e-6, 0), ("y0", 0, -40e-6), ("y1", 0, 40e-6))]  # fmt: skip
    out = tmp_path / "camera.json"
    argv = ["vision", "calibrate", "--x-move", "100um", *images[:2], "--y-move", "80um", *images[2:]]
    assert main([*argv, "--out", str(out), "--json"]) == 0
    assert json.loads(out.read_text()).get("origin_x_px") is None
    capsys.readouterr()
    check = _write(tmp_path / "check.png", renderer, 30e-6, 20e-6, 0.2)
    assert main(["vision", "locate", check, "--calibration", str(out), "--part", "300x300x50", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    centre = (CameraModel().width_px - 1) / 2, (CameraModel().height_px - 1) / 2
    assert report["origin_px"] == list(centre) and "image centre" in report["note"]
    about_centre = CameraCalibration(TRUE.pixel_size_m, TRUE.rotation_rad, TRUE.mirrored, *centre)
    expected = about_centre.to_plate(*TRUE.to_image(30e-6, 20e-6))
    (part,) = report["parts"]
    assert (part["plate_x_m"], part["plate_y_m"]) == pytest.approx(expected, abs=0.5e-6)


def test_locate_cli_json_units_plot_and_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    renderer = FrameRenderer(CameraModel(part_level=0.1).with_noise(0.02), seed=5)
    path = tmp_path / "frame.png"
    cv2.imwrite(
        str(path),
        renderer.render(
            [PartInImage(400.4, 600.7, 2.5, 300, 150, mark=True), PartInImage(1000, 300, 0.0, 300, 150)]
        ),
    )
    plot = tmp_path / "plot.png"
    assert (
        main(
            [
                "vision",
                "locate",
                str(path),
                "--pixel-size",
                "1µm",
                "--part",
                "300x150x50",
                "--mark",
                "--plot",
                str(plot),
                "--json",
            ]
        )
        == 0
    )
    report = json.loads(capsys.readouterr().out)
    assert (report["width"], report["height"], report["polarity"]) == (1024, 1024, "dark")
    (part,) = report["parts"]
    assert part["x_px"] == pytest.approx(400.4, abs=0.05) and part["y_px"] == pytest.approx(600.7, abs=0.05)
    assert part["angle_rad"] == pytest.approx(2.5, abs=1e-3)
    assert part["x_m"] == pytest.approx(400.4e-6, abs=5e-8)
    assert report["rejected"][0]["reason"] == "cut by the image border"
    assert plot.stat().st_size > 1000
    with pytest.raises(SystemExit) as usage:
        main(["vision", "locate", str(path), "--pixel-size", "1furlong"])
    assert usage.value.code == 2 and "--pixel-size" in capsys.readouterr().err
    assert main(["vision", "locate", str(path), "--part", "300x300x50"]) == 2
    assert "--part: needs --pixel-size" in capsys.readouterr().err
    with pytest.raises(SystemExit) as usage:  # checked by the argument's type
        main(["vision", "locate", str(tmp_path / "missing.png")])
    err = capsys.readouterr().err
    assert usage.value.code == 2 and "no such file: " in err and "missing.png" in err


def test_grab_cli_writes_a_png(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), np.full((20, 30), 77, np.uint16))
    out = tmp_path / "grab.png"
    assert main(["vision", "grab", str(folder), "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["width"], report["height"], report["dtype"]) == (30, 20, "uint16")
    assert int(cv2.imread(str(out), cv2.IMREAD_UNCHANGED)[0, 0]) == 77
    assert main(["vision", "grab", str(tmp_path / "nope"), "--out", str(out)]) == 2
    capsys.readouterr()
    assert main(["vision", "grab", "/dev/null", "--out", str(tmp_path / "null.png")]) == 2
    error = capsys.readouterr().err.strip()  # the camera named once, not "/dev/null: /dev/null: ..."
    assert error.count("/dev/null") == 1 and "not a camera or stream OpenCV" in error
    assert not (tmp_path / "null.png").exists()
