"""A camera calibration report's way out: ``--out`` JSON, ``--save-state`` for the daemon, the
printed line or ``--json`` (``feeder vision calibrate`` and ``calibrate-moves``)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from feeder.cli.output import print_json
from feeder.errors import InputError
from feeder.files import write_text

CALIBRATION_NOTE = "printed only: --out writes it as JSON, --save-state stores it for the daemon"


def check_target(path: Path | None, flag: str) -> None:
    """Refuse (before any work) an output path that cannot be written."""
    if path is not None and (path.is_dir() or not path.parent.is_dir()):
        raise InputError(flag, f"cannot write {path}: a directory, or its directory does not exist")


def save_state(state_dir: Path | None, calibration: dict[str, Any]) -> Path:
    """Store ``calibration`` (its fields that have a value) in the daemon's SQLite state
    (one-line error if it is not ours)."""
    from feeder.daemon.config import default_state_dir
    from feeder.daemon.store import Store, StoreError

    path = (state_dir or default_state_dir()) / "feeder.sqlite"
    try:
        store = Store(path)
    except (StoreError, OSError) as err:
        raise InputError("--state-dir", str(err)) from None
    try:
        store.save_camera_calibration(calibration)
    finally:
        store.close()
    return path


def emit_calibration(report: dict[str, Any], args: argparse.Namespace) -> int:
    """Write, store and print ``report`` (pixel_size_m, rotation_rad, mirrored, origin_*_px ...)
    as ``args.out``, ``args.save_state``/``args.state_dir`` and ``args.json`` ask."""
    calibration = {k: v for k, v in report.items() if v is not None}
    if args.out is None and not args.save_state and "note" not in report:
        report["note"] = CALIBRATION_NOTE
    if args.out is not None:
        write_text(args.out, json.dumps(calibration, indent=2) + "\n")
        report["out"] = str(args.out)
    if args.save_state:
        report["database"] = str(save_state(args.state_dir, calibration))
    if args.json:
        print_json(report)
    else:
        turn = math.degrees(report["rotation_rad"])
        print(
            f"pixel size {report['pixel_size_m'] * 1e6:.5f} µm, rotation {turn:.4f}°"
            f"{', mirrored' if report['mirrored'] else ''}"
            + (
                f", θ centre ({report['origin_x_px']:.2f}, {report['origin_y_px']:.2f})"
                + (f" ± {report['origin_uncertainty_px']:.2f}" if "origin_uncertainty_px" in report else "")
                + " px"
                if report["origin_x_px"] is not None
                else ""
            )
        )
        if "note" in report:
            print(report["note"])
    return 0
