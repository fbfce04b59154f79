"""Make docs/console.png: the console in headless Chromium on the embedded simulator with its camera.

python docs/console_screenshot.py   (needs Debian's chromium and the playwright package)
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

from feeder.daemon.client import Client
from feeder.daemon.store import Store

ROOT = Path(__file__).resolve().parents[1]
PIXEL_M = 5e-6


def main() -> None:
    base = Path(tempfile.mkdtemp(prefix="fs"))
    state = base / "state"
    state.mkdir(mode=0o700)
    store = Store(state / "feeder.sqlite")  # the simulator's camera: plate origin at the image centre
    store.save_camera_calibration(
        {
            "pixel_size_m": PIXEL_M,
            "rotation_rad": 0.0,
            "mirrored": False,
            "origin_x_px": 511.5,
            "origin_y_px": 511.5,
        }
    )
    store.close()
    daemon = subprocess.Popen(
        [sys.executable, "-m", "feeder", "daemon", "--json", "--state-dir", str(state),
         "--socket", str(base / "s.sock"),
         "--http", "127.0.0.1:0", "--sim-arg=--camera-http=0", f"--sim-arg=--camera-pixel-size-m={PIXEL_M}"],
        cwd=ROOT, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert daemon.stdout is not None
        lines = []
        for line in daemon.stdout:
            lines.append(line)
            if line.rstrip() == "}":
                break
        ready = json.loads("".join(lines))
        with Client(base / "s.sock", timeout_s=60) as client:
            client.move_to(800e-6)
            client.move_to(-600e-6)
        with sync_playwright() as playwright, Client(base / "s.sock", timeout_s=60) as client:
            browser = playwright.chromium.launch(
                executable_path="/usr/bin/chromium", args=["--no-sandbox", "--disable-gpu"]
            )
            page = browser.new_page(viewport={"width": 1280, "height": 1180})
            page.goto(ready["console_url"])
            time.sleep(1.0)
            client.move_to(1.2e-3)  # watched live: the last move's plot
            time.sleep(0.5)
            box = page.locator("#view").bounding_box()
            page.mouse.click(box["x"] + box["width"] * 0.62, box["y"] + box["height"] * 0.5)
            time.sleep(0.5)
            page.screenshot(path=str(ROOT / "docs" / "console.png"))
            browser.close()
    finally:
        daemon.terminate()
        daemon.wait(20)
        shutil.rmtree(base, ignore_errors=True)


if __name__ == "__main__":
    main()
