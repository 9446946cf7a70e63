"""The README's picture of the 3D viewer: writes a run's viewer, opens it in headless Chromium (the system's
``chromium`` through playwright), shows the worst clip by limb agreement in every style of its source at one
second in, and saves a PNG.

    .venv/bin/python docs/viewer_screenshot.py RUN --out docs/viewer.png      (or: make docs-screenshot RUN=...)
"""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path

from motionaug.augment.render.viewer import write_run_viewer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs/viewer.png"))
    parser.add_argument("--seconds", type=float, default=1.0)
    parser.add_argument("--chromium", default=os.environ.get("MOTIONAUG_CHROMIUM") or shutil.which("chromium"))
    args = parser.parse_args()
    if not args.chromium:
        raise SystemExit("no chromium on PATH (make browser, or --chromium PATH)")
    from playwright.sync_api import sync_playwright

    page_path = write_run_viewer(args.run).page
    with sync_playwright() as manager:
        browser = manager.chromium.launch(executable_path=args.chromium)
        page = browser.new_page(viewport={"width": 1280, "height": 720})
        page.goto(page_path.resolve().as_uri())
        page.wait_for_function("window.motionViewer && motionViewer.ready")
        page.click("#play")  # pause
        for box in page.locator("#styles input").all():  # every style of the selected clip's source
            if not box.is_checked():
                page.evaluate("motionViewer.ready = false")
                box.check()
                page.wait_for_function("motionViewer.ready")
        page.evaluate(f"motionViewer.seek({args.seconds})")
        page.screenshot(path=str(args.out))
        browser.close()
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
