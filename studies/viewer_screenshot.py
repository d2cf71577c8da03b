"""Screenshot of the viewer on a model, as the README shows it: the real page in headless chromium (tools.browser).

    python -m studies viewer-screenshot [--model models/default] [--displacement-mm 10] [--angle-deg 0]
                                        [--targets 1] [--zoom 1.6] [--publish]

Starts `python -m service --model M`, opens /viewer, moves the sliders as a user would, clicks the
prostate `--targets` times (tools.browser.add_target), zooms towards the prostate with the
mouse wheel until the camera is `--zoom` times closer, and saves the page, 1280 x 800, as
runs/viewer.png, or with --publish as docs/img/viewer.png (the image the docs show).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from service.settings import DEFAULT_MODEL
from studies.results import ROOT
from tools.browser import add_target, open_viewer, set_slider, wait_still
from tools.loadtest import local_service


def zoom(page, factor: float) -> None:
    """Turn the mouse wheel over the view until the camera is `factor` times closer
    (OrbitControls dollies to the prostate)."""
    distance = lambda: page.evaluate("__viewer.cameraDistance()")  # noqa: E731
    goal = distance() / factor
    page.mouse.move(300, 300)
    while distance() > goal:
        page.mouse.wheel(0, -20)
        page.wait_for_timeout(20)


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies viewer-screenshot", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    ap.add_argument("--displacement-mm", type=float, default=10.0)
    ap.add_argument("--angle-deg", type=float, default=0.0)
    ap.add_argument("--targets", type=int, default=1, help="prostate clicks, each a target")
    ap.add_argument("--zoom", type=float, default=1.6, help="camera this many times closer than the page's default")
    ap.add_argument("--publish", action="store_true", help="write docs/img/viewer.png instead of runs/viewer.png")
    args = ap.parse_args(argv)
    args.out = (ROOT / "docs" / "img" if args.publish else ROOT / "runs") / "viewer.png"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with local_service("--model", str(args.model)) as url, open_viewer(url) as (page, problems):
        zoom(page, args.zoom)
        for _ in range(args.targets):  # at rest, so the line shows the whole motion
            add_target(page)
        set_slider(page, "angle", args.angle_deg)
        state = set_slider(page, "displacement", args.displacement_mm)
        wait_still(page)  # the full-resolution frame, not a drag's
        page.screenshot(path=args.out)
        if problems:
            raise SystemExit("error: " + "; ".join(problems))
        moved = page.evaluate("__viewer.targets.map((t) => t.motionMm.toFixed(2))")
        print(f"{args.out}: {args.model.name} at {state['lastFrame']['displacement_mm']} mm, "
              f"{state['lastFrame']['angle_deg']} deg; targets moved {', '.join(moved) or 'none'} mm")
