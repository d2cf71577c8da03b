"""Drive the viewer in a real browser: Debian's chromium under Playwright (the dev extra; never a downloaded browser).

For the viewer's tests and `python -m bench viewer|viewer-backends`; the service never imports this module.
Without a GPU, WebGL runs in software: on Mesa's llvmpipe through ANGLE's GL-EGL backend where
Mesa's EGL is installed (`make system-deps`), else on chromium's own SwiftShader. Measured on the
default model at 1280 x 800 (`python -m bench viewer-backends`, docs/viewer.md): SwiftShader's GPU
process spent about 260 ms of CPU per frame and llvmpipe's about 110, on the 2 cores the service
shares, so llvmpipe is preferred.
"""

from __future__ import annotations

import ctypes.util
import shutil
import threading
import time
from contextlib import contextmanager
from typing import Iterator

from .loadtest import free_port

CHROMIUM = ("chromium", "chromium-browser")
SWIFTSHADER_FLAGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
# chromium blocklists llvmpipe as a software GL; unblocked, WebGL 2 runs on it.
LLVMPIPE_FLAGS = ["--use-angle=gl-egl", "--ignore-gpu-blocklist", "--enable-unsafe-swiftshader"]


def webgl_flags() -> list[str]:
    """Chromium's flags for software WebGL: Mesa's llvmpipe where libEGL_mesa is installed, else SwiftShader."""
    return LLVMPIPE_FLAGS if ctypes.util.find_library("EGL_mesa") else SWIFTSHADER_FLAGS


def find_chromium() -> str | None:
    """Path of a chromium on PATH (`make system-deps` installs Debian's), or None."""
    return next((path for path in map(shutil.which, CHROMIUM) if path), None)


@contextmanager
def serve_in_thread(app, *, timeout_s: float = 30.0) -> Iterator[str]:
    """Run `app` under uvicorn on a free loopback port in this process; yields its base URL."""
    import uvicorn

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, name="uvicorn", daemon=True)
    thread.start()
    deadline = time.monotonic() + timeout_s
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError("uvicorn did not start")
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout_s)


@contextmanager
def launch_chromium(flags: list[str] | None = None) -> Iterator[object]:
    """A headless Playwright browser on the chromium found on PATH,
    WebGL in software (`flags`, default `webgl_flags()`)."""
    from playwright.sync_api import sync_playwright

    executable = find_chromium()
    if executable is None:
        raise FileNotFoundError("no chromium on PATH (make system-deps installs it)")
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=executable, args=webgl_flags() if flags is None else flags)
        try:
            yield browser
        finally:
            browser.close()


@contextmanager
def open_viewer(url: str, *, browser=None, width: int = 1280, height: int = 800,
                watch: bool = True, query: str = "") -> Iterator[tuple[object, list[str]]]:
    """(page, problems) with /viewer loaded and its first frame drawn, in `browser` or a chromium of its own.

    With `watch`, problems collects console errors, page errors and any request that leaves
    `url` (the page must work offline); benchmarks leave it off, since every watched request
    is an event for the driver to handle on the same cores. `query` is the page URL's query string
    ("antialias=1" turns multisampling on whatever the renderer).
    """
    if browser is None:
        with launch_chromium() as own, open_viewer(url, browser=own, width=width, height=height, watch=watch,
                                                   query=query) as opened:
            yield opened
        return
    problems: list[str] = []
    page = browser.new_page(viewport={"width": width, "height": height})
    try:
        if watch:
            page.on("console", lambda m: m.type == "error" and problems.append(f"console: {m.text}"))
            page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
            page.on("request", lambda r: r.url.startswith(url) or problems.append(f"request off the service: {r.url}"))
        page.goto(f"{url}/viewer{'?' + query if query else ''}")
        page.wait_for_function("window.__viewer && window.__viewer.frames >= 1", timeout=60_000)
        yield page, problems
    finally:
        page.close()


def set_slider(page, slider: str, value: float, *, timeout_ms: float = 30_000) -> dict:
    """Move a slider ("displacement" or "angle") as a user would and wait for the frame that shows it."""
    key = {"displacement": "displacement_mm", "angle": "angle_deg"}[slider]
    page.fill(f"#{slider}", str(value))  # sets the value and fires `input`, like a drag's last step
    page.wait_for_function(f"(v) => window.__viewer.lastFrame && Math.abs(window.__viewer.lastFrame.{key} - v) < 1e-9 "
                           "&& !window.__viewer.busy", arg=value, timeout=timeout_ms)
    return page.evaluate("({lastFrameMs: __viewer.lastFrameMs, lastFetchMs: __viewer.lastFetchMs, "
                         "frames: __viewer.frames, lastFrame: __viewer.lastFrame})")


def wait_still(page, *, timeout_ms: float = 30_000) -> None:
    """Wait until the view is drawn at full resolution (a software renderer draws a drag's frames at
    less, then a still frame: viewer.js, DRAG_SCALE): before a screenshot."""
    page.wait_for_function("window.__viewer.still && !window.__viewer.busy", timeout=timeout_ms)


# A drag inside the page: each step sets the slider and fires `input` as the browser does while a
# user drags, waits for the frame that shows it (the page's 'viewer-frame' event, so the wait
# itself takes no CPU from the page and the service), then pauses (a hand moves at a few tens of Hz).
DRAG = """async ([id, values, pauseMs]) => {
  const slider = document.getElementById(id), out = [];
  const drawn = () => new Promise(
    (resolve) => window.addEventListener('viewer-frame', (e) => resolve(e.detail), { once: true }));
  for (const value of values) {
    const next = drawn();
    slider.value = String(value);
    slider.dispatchEvent(new Event('input', { bubbles: true }));
    let frame = await next;
    while (window.__viewer.busy) frame = await drawn();  // something else (a target) asked for a frame meanwhile
    out.push(frame);
    await new Promise((r) => setTimeout(r, pauseMs));
  }
  return out; }"""

# A paced drag: `input` every intervalMs whether or not the last frame is drawn, as a pointer
# moving at 1000 / intervalMs Hz would fire it; the page coalesces what arrives during a fetch.
# Returns every frame drawn meanwhile (the page's 'viewer-frame' events) and the inputs fired.
PACED_DRAG = """async ([id, values, intervalMs]) => {
  const slider = document.getElementById(id), frames = [];
  const listen = (e) => frames.push(e.detail);
  window.addEventListener('viewer-frame', listen);
  const start = performance.now();
  for (let i = 0; i < values.length; i++) {
    const wait = start + i * intervalMs - performance.now();
    if (wait > 0) await new Promise((r) => setTimeout(r, wait));
    slider.value = String(values[i]);
    slider.dispatchEvent(new Event('input', { bubbles: true }));
  }
  while (window.__viewer.busy) await new Promise((r) => setTimeout(r, 1));
  window.removeEventListener('viewer-frame', listen);
  return { frames, inputs: values.length, seconds: (performance.now() - start) / 1000 }; }"""


def drag(page, slider: str, values, *, pause_ms: float = 30.0) -> list[dict]:
    """Move a slider through `values` from inside the page, one frame each; the page's own figures for each frame."""
    return page.evaluate(DRAG, [slider, [float(v) for v in values], pause_ms])


def paced_drag(page, slider: str, values, *, interval_ms: float = 1000 / 60) -> dict:
    """Fire the slider's `input` through `values` every `interval_ms` from inside the page; the frames drawn.

    {"frames": [page figures per frame], "inputs": len(values), "seconds": how long it took}.
    """
    return page.evaluate(PACED_DRAG, [slider, [float(v) for v in values], interval_ms])


def add_target(page, *, timeout_ms: float = 30_000) -> dict:
    """Click the prostate as a user would and wait for the frame that shows the new target; that target."""
    count = page.evaluate("__viewer.targets.length")
    point = page.evaluate("__viewer.prostateScreenPoint()")
    page.mouse.click(point["x"], point["y"])
    page.wait_for_function("(n) => __viewer.targets.length === n && __viewer.targets[n - 1].motionMm !== null "
                           "&& !__viewer.busy", arg=count + 1, timeout=timeout_ms)
    return page.evaluate("__viewer.targets[__viewer.targets.length - 1]")
