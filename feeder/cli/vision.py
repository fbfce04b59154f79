"""``feeder vision``: locate parts in an image, grab a camera frame, calibrate the camera (docs/vision.md)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from feeder.cli import vision_moves
from feeder.cli.arguments import angle_rad, input_path, length_in, length_m, output_path, positive_float
from feeder.cli.calibration_report import check_target, emit_calibration
from feeder.cli.output import print_json
from feeder.errors import InputError
from feeder.files import read_text, save_figure, write_bytes
from feeder.parts import Part
from feeder.vision.calibration import (
    CameraCalibration,
    axes_from_moves,
    pixel_size_from_part,
    rotation_centre,
)
from feeder.vision.model import Detection, LocateResult, PartTemplate


def register(sub: Any) -> None:
    p = sub.add_parser("vision", help="pose of parts from camera images, camera frames, calibration")
    vision = p.add_subparsers(dest="vision_command", required=True, parser_class=type(p))

    locate = vision.add_parser("locate", help="every part's centre and angle in one image")
    locate.add_argument(
        "image", type=input_path, metavar="IMAGE", help="PNG/TIFF/JPEG, grey or colour, 8/16 bit"
    )
    locate.add_argument(
        "--pixel-size",
        type=length_in(1e-9, 1e-2),
        metavar="LENGTH",
        help="pixel size on the plate, 1 nm–10 mm, e.g. 1um, 1µm or 1e-6 (adds x_m, y_m)",
    )
    locate.add_argument("--part", help="LxWxT in µm (needs --pixel-size): refuse other sizes; angle of L")
    locate.add_argument("--disc", action="store_true", help="round parts (--part's L is the diameter)")
    locate.add_argument("--mark", action="store_true", help="parts carry the orientation mark (angle mod 2π)")
    locate.add_argument(
        "--polarity",
        choices=("auto", "bright", "dark"),
        default="auto",
        help="parts brighter or darker than the support (default: auto)",
    )
    locate.add_argument(
        "--calibration", type=input_path, help="JSON of `feeder vision calibrate`: adds plate poses"
    )
    locate.add_argument("--plot", type=output_path, help="PNG of the image with the outlines found")
    locate.add_argument("--json", action="store_true", help="print one JSON object")
    locate.set_defaults(handler=run_locate)

    grab = vision.add_parser("grab", help="save one frame of a camera")
    grab.add_argument(
        "camera",
        metavar="URL",
        help="stream URL, camera index, video file, image folder or genicam:PRODUCER.cti[#SERIAL]",
    )
    grab.add_argument("--out", type=output_path, required=True, help="PNG to write (lossless)")
    grab.add_argument(
        "--timeout-s", type=positive_float, default=10.0, help="wait this long for a frame, s (default 10)"
    )
    grab.add_argument("--json", action="store_true", help="print one JSON object")
    grab.set_defaults(handler=run_grab)

    cal = vision.add_parser("calibrate", help="pixel size and camera-to-plate transform from images")
    cal.add_argument("--part", help="LxWxT in µm of the part in the images")
    cal.add_argument(
        "--image",
        type=input_path,
        action="append",
        default=[],
        help="an image of the part (repeatable): pixel size from its known size",
    )
    for axis in ("x", "y"):
        cal.add_argument(
            f"--{axis}-move",
            nargs=3,
            action="append",
            default=[],
            metavar=("DISTANCE", "BEFORE", "AFTER"),
            help=f"images of the part before and after a plate move along {axis} (repeatable)",
        )
    cal.add_argument(
        "--theta-move",
        nargs=3,
        action="append",
        default=[],
        metavar=("ANGLE", "BEFORE", "AFTER"),
        help="images before and after a plate turn, e.g. 5deg (repeatable): the θ centre",
    )
    cal.add_argument(
        "--out", type=output_path, help="write the calibration JSON (read by `locate --calibration`)"
    )
    cal.add_argument(
        "--save-state",
        action="store_true",
        help="also store it in the daemon's state database, beside the step calibration (see --state-dir)",
    )
    cal.add_argument(
        "--state-dir", type=Path, help="the daemon's state directory (default: $XDG_STATE_HOME/feeder)"
    )
    cal.add_argument("--json", action="store_true", help="print one JSON object")
    cal.set_defaults(handler=run_calibrate)
    vision_moves.register(vision)


def _read_image(path: Path) -> np.ndarray:
    import cv2

    if not path.is_file():
        raise InputError(str(path), "no such file")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(str(path), "not an image OpenCV can read")
    return image


def _template(args: argparse.Namespace) -> PartTemplate | None:
    if args.part is None:
        if args.disc or args.mark:
            raise InputError("--part", "--disc and --mark need the part's size")
        return None
    if args.pixel_size is None:
        raise InputError("--part", "needs --pixel-size to turn µm into pixels")
    part = Part.parse(args.part)
    return PartTemplate(part.length_m / args.pixel_size, part.width_m / args.pixel_size, args.disc, args.mark)


def _load_calibration(path: Path) -> tuple[CameraCalibration, bool]:
    """The calibration in ``path`` (JSON of `feeder vision calibrate`), and whether it gives the
    θ centre O (a calibration without ``--theta-move`` does not: its origin is null)."""
    try:
        data = json.loads(read_text(path))
        origin = data.get("origin_x_px"), data.get("origin_y_px")
        calibration = CameraCalibration(
            float(data["pixel_size_m"]),
            float(data["rotation_rad"]),
            bool(data["mirrored"]),
            *(0.0 if v is None else float(v) for v in origin),
        )
    except FileNotFoundError:
        raise InputError(str(path), "no such file") from None
    except KeyError as err:
        raise InputError(
            str(path), f"no {err}: not a calibration JSON of `feeder vision calibrate`"
        ) from None
    except (OSError, ValueError, TypeError, AttributeError) as err:
        raise InputError(str(path), f"not a calibration JSON of `feeder vision calibrate`: {err}") from None
    return calibration, None not in origin


def _part_json(
    part: Detection, pixel_size: float | None, calibration: CameraCalibration | None
) -> dict[str, Any]:
    out: dict[str, Any] = {
        "x_px": part.x_px,
        "y_px": part.y_px,
        "angle_rad": part.angle_rad,
        "score": part.score,
        "length_px": part.length_px,
        "width_px": part.width_px,
        "edge_rms_px": part.edge_rms_px,
        "symmetry_rad": part.symmetry_rad,
        "disc": part.disc,
    }
    if pixel_size is not None:
        out.update(
            x_m=part.x_px * pixel_size,
            y_m=part.y_px * pixel_size,
            length_m=part.length_px * pixel_size,
            width_m=part.width_px * pixel_size,
        )
    if calibration is not None:
        x, y = calibration.to_plate(part.x_px, part.y_px)
        out.update(plate_x_m=x, plate_y_m=y, plate_psi_rad=calibration.angle_to_plate(part.angle_rad))
    return out


def run_locate(args: argparse.Namespace) -> int:
    from feeder.vision.locate import locate

    check_target(args.plot, "--plot")
    calibration, origin = _load_calibration(args.calibration) if args.calibration else (None, False)
    if args.pixel_size is None and calibration is not None:
        args.pixel_size = calibration.pixel_size_m
    template = _template(args)
    image = _read_image(args.image)
    if calibration is not None and not origin:  # no θ turns measured O: the image centre, as the daemon
        height, width = image.shape[:2]
        calibration = dataclasses.replace(
            calibration, origin_x_px=(width - 1) / 2, origin_y_px=(height - 1) / 2
        )
    try:
        result = locate(image, template, args.polarity)
    except ValueError as err:
        raise InputError(str(args.image), str(err)) from None
    report: dict[str, Any] = {
        "image": str(args.image),
        "width": result.width,
        "height": result.height,
        "polarity": result.polarity,
        "pixel_size_m": args.pixel_size,
        "parts": [_part_json(p, args.pixel_size, calibration) for p in result.parts],
        "rejected": [{"x_px": r.x_px, "y_px": r.y_px, "reason": r.reason} for r in result.rejected],
        "convention": "origin at the centre of the top-left pixel, x right, y down; angle of the part's "
        "first dimension from +x towards +y, modulo symmetry_rad",
    }
    if calibration is not None:
        report["origin_px"] = [calibration.origin_x_px, calibration.origin_y_px]
        if not origin:
            report["note"] = "plate coordinates about the image centre: the calibration has no θ turns"
    if args.plot is not None:
        _plot(image, result, args.plot)
        report["plot"] = str(args.plot)
    if args.json:
        print_json(report)
        return 0
    print(
        f"{args.image}: {result.width}×{result.height}, {len(result.parts)} part(s), {result.polarity} parts"
    )
    if "note" in report:
        print(f"  ({report['note']})")
    for i, p in enumerate(result.parts, 1):
        print(
            f"  {i}: x {p.x_px:.3f} px  y {p.y_px:.3f} px  angle {math.degrees(p.angle_rad):.3f}°  "
            f"score {p.score:.2f}"
        )
    for r in result.rejected:
        print(f"  refused at ({r.x_px:.0f}, {r.y_px:.0f}) px: {r.reason}")
    return 0


def _outline(part: Detection) -> np.ndarray:
    """The part's outline (px): its rectangle, or a circle for a disc."""
    if part.disc:
        t = np.linspace(0, 2 * math.pi, 181)
        return np.column_stack(
            [part.x_px + part.length_px / 2 * np.cos(t), part.y_px + part.length_px / 2 * np.sin(t)]
        )
    c, s = math.cos(part.angle_rad), math.sin(part.angle_rad)
    u = np.array([1, -1, -1, 1, 1]) * part.length_px / 2
    v = np.array([1, 1, -1, -1, 1]) * part.width_px / 2
    return np.column_stack([part.x_px + u * c - v * s, part.y_px + u * s + v * c])


def _plot(image: np.ndarray, result: LocateResult, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 7 * result.height / result.width))
    ax.imshow(image if image.ndim == 2 else image[..., ::-1], cmap="gray", interpolation="nearest")
    for i, part in enumerate(result.parts, 1):
        outline = _outline(part)
        ax.plot(outline[:, 0], outline[:, 1], color="lime", lw=1)
        arrow = 0.35 * part.length_px
        ax.annotate(
            "",
            (part.x_px + arrow * math.cos(part.angle_rad), part.y_px + arrow * math.sin(part.angle_rad)),
            (part.x_px, part.y_px),
            arrowprops={"arrowstyle": "->", "color": "lime"},
        )
        ax.text(part.x_px, part.y_px, f" {i}", color="lime")
    for r in result.rejected:
        ax.plot(r.x_px, r.y_px, "x", color="red", ms=12)
        ax.text(r.x_px, r.y_px, " " + r.reason, color="red", fontsize=7)
    ax.set_title(f"{len(result.parts)} part(s) located, {len(result.rejected)} refused")
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    fig.tight_layout()
    save_figure(fig, path)


def run_grab(args: argparse.Namespace) -> int:
    import cv2

    from feeder.drivers.frame_source import CameraLost
    from feeder.drivers.video_camera import CameraError, open_camera

    check_target(args.out, "--out")
    try:
        with open_camera(args.camera) as camera:
            frame = camera.read(timeout_s=args.timeout_s)
    except (CameraError, CameraLost) as err:  # the camera's messages start with its name
        raise InputError(args.camera, str(err).removeprefix(f"{args.camera}: ")) from None
    ok, data = cv2.imencode(".png", frame.image)
    if not ok:
        raise InputError(args.camera, "the frame cannot be encoded as PNG")
    write_bytes(args.out, data.tobytes())
    report = {
        "camera": args.camera,
        "out": str(args.out),
        "width": int(frame.image.shape[1]),
        "height": int(frame.image.shape[0]),
        "dtype": str(frame.image.dtype),
        "channels": 1 if frame.image.ndim == 2 else int(frame.image.shape[2]),
        "sequence": frame.sequence,
        "source_time_s": frame.source_time_s,
    }
    if args.json:
        print_json(report)
    else:
        print(f"{args.out}: {report['width']}×{report['height']} {report['dtype']} frame of {args.camera}")
    return 0


def _one_part(path: Path) -> Detection:
    from feeder.vision.locate import locate

    result = locate(_read_image(path))
    if len(result.parts) != 1:
        reasons = "; ".join(r.reason for r in result.rejected)
        raise InputError(
            str(path),
            f"expected one part, found {len(result.parts)}" + (f" (refused: {reasons})" if reasons else ""),
        )
    return result.parts[0]


def _length(text: str, flag: str) -> float:
    try:
        return length_m(text)
    except argparse.ArgumentTypeError as err:
        raise InputError(flag, str(err)) from None


def run_calibrate(args: argparse.Namespace) -> int:
    check_target(args.out, "--out")
    report: dict[str, Any] = {}
    if args.image:
        if args.part is None:
            raise InputError("--part", "required with --image (the pixel size comes from its size)")
        part = Part.parse(args.part)
        sizes = [
            pixel_size_from_part(d.length_px, d.width_px, part.length_m, part.width_m)
            for d in map(_one_part, args.image)
        ]
        report["pixel_size_from_part_m"] = float(np.mean(sizes))
    plate, image = [], []
    for axis, moves in (("x", args.x_move), ("y", args.y_move)):
        for distance, before, after in moves:
            d = _length(distance, f"--{axis}-move")
            a, b = _one_part(Path(before)), _one_part(Path(after))
            plate.append((d, 0.0) if axis == "x" else (0.0, d))
            image.append((b.x_px - a.x_px, b.y_px - a.y_px))
    pixel_size = report.get("pixel_size_from_part_m")
    rotation, mirrored = 0.0, False
    if plate:
        fit = axes_from_moves(np.array(plate), np.array(image))
        report.update(
            pixel_size_from_moves_m=fit.pixel_size_m,
            rotation_rad=fit.rotation_rad,
            mirrored=fit.mirrored,
            moves_residual_px=fit.residual_px,
            anisotropy=fit.anisotropy,
        )
        pixel_size, rotation, mirrored = fit.pixel_size_m, fit.rotation_rad, fit.mirrored
    if args.theta_move:
        before_px, after_px, turns = [], [], []
        for angle, before, after in args.theta_move:
            try:
                turns.append(angle_rad(angle))
            except argparse.ArgumentTypeError as err:
                raise InputError("--theta-move", str(err)) from None
            a, b = _one_part(Path(before)), _one_part(Path(after))
            before_px.append((a.x_px, a.y_px))
            after_px.append((b.x_px, b.y_px))
        ox, oy, residual = rotation_centre(np.array(before_px), np.array(after_px), np.array(turns), mirrored)
        report.update(origin_x_px=ox, origin_y_px=oy, theta_residual_px=residual)
    if pixel_size is None:
        raise InputError("--image", "give --part with --image, or --x-move and --y-move")
    report = {
        "pixel_size_m": pixel_size,
        "rotation_rad": rotation,
        "mirrored": mirrored,
        "origin_x_px": report.get("origin_x_px"),
        "origin_y_px": report.get("origin_y_px"),
        **report,
    }
    return emit_calibration(report, args)
