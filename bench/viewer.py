"""Slider-to-frame latency of the viewer in headless chromium (software WebGL), and what each way of fetching a frame costs.

    python -m bench viewer [--model models/default] [--moves 200] [--pause-ms 30] [--interval-ms 16.7] [--rounds 50]

Starts `python -m service` on a loopback port, opens /viewer and prints the page's own figures
(window.__viewer, the 'viewer-frame' events):
  * stepwise drag: `--moves` slider values, each step fires `input`, waits for its frame and
    pauses `--pause-ms` (tools.browser.drag); without targets, then with one clicked target.
    Slider to frame is from the input event to WebGL finished (gl.finish); with the /predict
    replies (fetch, split by the page's Resource Timing) and the render as parts of it;
  * paced drag: `--moves` inputs every `--interval-ms` whatever the frames do, as a pointer fires
    them (tools.browser.paced_drag). The page keeps one frame in flight and coalesces the rest,
    so a frame is timed from the latest input it shows and, separately, from the first input it
    answers (the oldest one coalesced into it);
  * fetch only: the ways a frame could be fetched, interleaved in each of `--rounds` rounds.
With `--trace FILE`, the paced drag runs under a chromium trace (Playwright's start_tracing) written
to FILE, and the WebGL commands the GPU process spent longest on are printed (where a render stall
sits).
"""  # noqa: E501 -- the first line is the command's summary in --list and its --help description

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from service.model import read_model_folder
from service.settings import DEFAULT_MODEL
from service.viewer import drawn_nodes, region_cover

from bench._report import Report
from studies import results
from tools.browser import add_target, drag, launch_chromium, open_viewer, paced_drag
from tools.loadtest import local_service

# `n` rounds; in each, every way (a list of /predict bodies fetched in parallel) once, in turn.
FETCH_ROUNDS = """async ([ways, n]) => { const out = ways.map(() => []);
  for (let i = 0; i < n; i++) for (const [j, bodies] of ways.entries()) {
    const t = performance.now();
    await Promise.all(bodies.map((b) => fetch('/predict', {
      method: 'POST', body: JSON.stringify({ ...b, angle_deg: i % 7 }),
      headers: { 'content-type': 'application/json', accept: 'application/octet-stream' },
    }).then((r) => r.arrayBuffer())));
    out[j].push(performance.now() - t);
  }
  return out; }"""


def _summary(ms) -> str:
    ms = np.asarray(ms)
    return f"p50 {np.percentile(ms, 50):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms, max {ms.max():.1f} ms"


def _stalls(frames, key: str = "frameMs", factor: float = 10.0) -> str:
    """Where the outliers are: frames slower than `factor` x the median, by index in the drag (0 = the first)."""
    ms = np.asarray([f[key] for f in frames])
    slow = np.flatnonzero(ms > factor * np.median(ms))
    if not len(slow):
        return f"no frame over {factor:g}x the median"
    return (f"{len(slow)} frame{'s' if len(slow) > 1 else ''} over {factor:g}x the median: "
            + ", ".join(f"#{i} {ms[i]:.0f} ms (render {frames[i]['renderMs']:.0f} ms)" for i in slow[:8]))


# Resource Timing of every /predict request since the last call: (sent, first byte, last byte) in ms from its start.
PREDICT_TIMINGS = """() => {
  const out = performance.getEntriesByType('resource').filter((e) => e.name.endsWith('/predict'))
  .map((e) => [e.requestStart - e.startTime, e.responseStart - e.startTime, e.responseEnd - e.startTime]);
  performance.clearResourceTimings(); return out; }"""


def _stepwise(page, values, pause_ms: float, label: str) -> None:
    page.evaluate("performance.setResourceTimingBufferSize(1_000_000); performance.clearResourceTimings()")
    frames = drag(page, "displacement", values, pause_ms=pause_ms)
    sent, first, last = np.asarray(page.evaluate(PREDICT_TIMINGS)).T
    print(f"  stepwise drag, {label}, {len(frames)} moves ({frames[-1]['requests']} /predict request a frame):")
    for name, ms in (("slider to frame (input event to WebGL finished)", [f["frameMs"] for f in frames]),
                     ("of which the /predict replies", [f["fetchMs"] for f in frames]),
                     ("  fetch() to request sent", sent), ("  request sent to the reply's first byte", first - sent),
                     ("  the reply's body", last - first),
                     ("of which the render (three.js + gl.finish)", [f["renderMs"] for f in frames])):
        print(f"    {name}: {_summary(ms)}")
    print(f"    stalls: {_stalls(frames)}")


# the command buffer traces each GL command under disabled-by-default-gpu.service once the decoder category is on
TRACE_CATEGORIES = ["toplevel", "gpu", "viz", "cc", "benchmark", "disabled-by-default-gpu.service",
                    "disabled-by-default-gpu.decoder"]


def _slow_gl_commands(path: Path, top: int = 6) -> list[str]:
    """The GL commands of a chromium trace with the longest single execution in the GPU process.

    The command buffer service traces each command as an async begin/end pair
    (`disabled-by-default-gpu.service`, e.g. kClear); pairs are matched by id, name and thread.
    """
    events = json.loads(path.read_text())
    events = events["traceEvents"] if isinstance(events, dict) else events
    began, took = {}, defaultdict(list)
    for e in sorted((e for e in events if e.get("cat") == "disabled-by-default-gpu.service" and e.get("ph") in "be"),
                    key=lambda e: e["ts"]):
        key = (e.get("id") or e.get("id2", {}).get("local"), e["name"], e["tid"])
        if e["ph"] == "b":
            began[key] = e["ts"]
        elif key in began:
            took[e["name"]].append((e["ts"] - began.pop(key)) / 1000)
    commands = {name: np.asarray(ms) for name, ms in took.items() if name.startswith("k")}
    return [f"{name}: {len(ms)} calls, p50 {np.median(ms):.2f} ms, max {ms.max():.0f} ms, "
            f"{ms.sum() / 1000:.1f} s in all"
            for name, ms in sorted(commands.items(), key=lambda kv: -kv[1].max())[:top]]


def _ways(folder, scene, case: dict) -> list[tuple[str, list[dict]]]:
    """(label, /predict bodies) of each way a frame could be fetched."""
    drawn = drawn_nodes(folder)
    near = min(folder.regions, key=lambda r: abs(len(folder.regions[r]) - len(drawn)))
    tissues = [t["name"] for t in scene["tissues"]]
    return [("the viewer's requests", [{**case, **({} if r is None else {"region": r})} for r in scene["regions"]]),
            ("region cover", [{**case, "region": r} for r in region_cover(folder, drawn)]),
            ("one request per drawn tissue", [{**case, "region": t} for t in [*tissues, "markers"]]),
            ("whole mesh, one request", [case]),
            (f"one region the size of the drawn nodes ({near}: {len(folder.regions[near]):,} nodes; "
             f"{len(drawn):,} drawn)", [{**case, "region": near}])]


def _query(args) -> str:
    """The /viewer query string of the options that override the page's own choices."""
    parts = {"auto": [], "on": ["antialias=1"], "off": ["antialias=0"]}[args.antialias]
    if args.scale is not None:
        parts.append(f"scale={args.scale:g}")
    return "&".join(parts)


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m bench viewer", description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    ap.add_argument("--moves", type=int, default=200)
    ap.add_argument("--pause-ms", type=float, default=30.0, help="stepwise drag: pause after each frame")
    ap.add_argument("--interval-ms", type=float, default=1000 / 60, help="paced drag: time between inputs")
    ap.add_argument("--rounds", type=int, default=50, help="fetch-only rounds")
    ap.add_argument("--antialias", choices=("auto", "on", "off"), default="auto",
                    help="multisampling: the page's choice (off on a software renderer), or forced "
                         "(/viewer?antialias=1 or 0)")
    ap.add_argument("--scale", type=float,
                    help="resolution of a drag's frames (/viewer?scale=): default the page's choice (0.5 on a software "
                         "renderer, then a still frame at full resolution); 1 keeps full resolution")
    ap.add_argument("--trace", type=Path,
                    help="write a chromium trace of the paced drag here and print its slowest GL commands")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    say = Report()
    folder = read_model_folder(args.model)
    with local_service("--model", str(args.model)) as url, launch_chromium() as browser, \
            open_viewer(url, browser=browser, watch=False, query=_query(args)) as (page, _):
        scene = page.evaluate("fetch('/viewer/scene.json').then((r) => r.json())")
        say(f"{scene['model']}: {len(folder.nodes):,} nodes; a frame asks /predict for "
              f"{', '.join(r or 'the whole mesh' for r in scene['regions'])}")
        say(f"  WebGL: {page.evaluate('__viewer.webgl')}, multisampling "
              f"{'on' if page.evaluate('__viewer.contextAntialias()') else 'off'}, a drag's frames at "
              f"{page.evaluate('__viewer.dragScale'):g} of full resolution")
        hi = page.evaluate("Number(document.getElementById('displacement').max)")
        values = np.round(np.linspace(0.0, hi, 41), 2)[np.arange(args.moves) % 41]
        _stepwise(page, values, args.pause_ms, "no targets")
        add_target(page)
        _stepwise(page, values, args.pause_ms, "one target")
        page.click("#clear-targets")
        if args.trace:
            browser.start_tracing(page=page, path=str(args.trace), categories=TRACE_CATEGORIES)
        paced = paced_drag(page, "displacement", np.round(np.linspace(0.0, hi, args.moves), 3),
                           interval_ms=args.interval_ms)
        if args.trace:
            browser.stop_tracing()
        frames = paced["frames"]
        say(f"  paced drag, {paced['inputs']} inputs every {args.interval_ms:.1f} ms over {paced['seconds']:.1f} s: "
              f"{len(frames)} frames, {np.mean([f['inputs'] for f in frames]):.1f} inputs a frame (max "
              f"{max(f['inputs'] for f in frames)}):")
        say(f"    latest input shown to frame: {_summary([f['frameMs'] for f in frames])}")
        say(f"    first input answered to frame: {_summary([f['firstInputMs'] for f in frames])}")
        say(f"    of which the /predict replies: {_summary([f['fetchMs'] for f in frames])}")
        say(f"    stalls: {_stalls(frames)}")
        if args.trace:
            say(f"    slowest GL commands in the GPU process (trace: {args.trace}):")
            for line in _slow_gl_commands(args.trace):
                say(f"      {line}")
        ways = _ways(folder, scene, {"displacement_mm": hi / 2})
        times = page.evaluate(FETCH_ROUNDS, [[bodies for _, bodies in ways], args.rounds])
        say(f"  fetch only, {args.rounds} rounds, the ways interleaved:")
        for (label, bodies), ms in zip(ways, times):
            say(f"    {label}, {len(bodies)} request{'s' if len(bodies) > 1 else ''}: {_summary(ms)}")
    print(f"wrote {results.write('bench_viewer', {'lines': say.lines}, publish=args.publish)}")
    return 0
