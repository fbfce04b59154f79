"""Make docs/console.png: the console in headless Chromium on the embedded default (the plane, its camera).

python docs/console_screenshot.py   (needs Debian's chromium and the playwright package)
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

from feeder.cli.demo_plane import wait_for_pose
from feeder.daemon.client import Client

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    base = Path(tempfile.mkdtemp(prefix="fs"))
    daemon = subprocess.Popen(  # the embedded default: the plane and its camera
        [sys.executable, "-m", "feeder", "daemon", "--json", "--state-dir", str(base / "state"),
         "--socket", str(base / "s.sock"), "--http", "127.0.0.1:0"],
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
        with Client(base / "s.sock", timeout_s=120) as client:
            wait_for_pose(client)
            client.move_to_pose(-0.6e-3, 0.3e-3, math.radians(20), timeout_s=120)
        with sync_playwright() as playwright, Client(base / "s.sock", timeout_s=120) as client:
            browser = playwright.chromium.launch(
                executable_path="/usr/bin/chromium", args=["--no-sandbox", "--disable-gpu"]
            )
            page = browser.new_page(viewport={"width": 1280, "height": 1180})
            page.goto(ready["console_url"])
            time.sleep(1.0)
            client.move_to_pose(0.9e-3, -0.2e-3, math.radians(-10), timeout_s=120)  # watched live
            time.sleep(0.5)
            box = page.locator("#view").bounding_box()  # a target: click, then drag its angle
            x, y = box["x"] + box["width"] * 0.35, box["y"] + box["height"] * 0.35
            page.mouse.move(x, y)
            page.mouse.down()
            page.mouse.move(x + 30, y - 18)
            page.mouse.up()
            time.sleep(0.5)
            page.screenshot(path=str(ROOT / "docs" / "console.png"))
            browser.close()
    finally:
        daemon.terminate()
        daemon.wait(20)
        shutil.rmtree(base, ignore_errors=True)


if __name__ == "__main__":
    main()
