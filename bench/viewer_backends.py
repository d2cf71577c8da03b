"""What each software WebGL backend and multisampling cost the viewer a frame, on this machine's CPUs.

    python -m bench viewer-backends [--model models/default] [--frames 20] [--moves 300]

For SwiftShader and Mesa's llvmpipe (tools.browser's two flag sets), with multisampling on and
off (/viewer?antialias=1 or 0; scale=1, every frame at full resolution), starts chromium on
/viewer of `python -m service` and prints:
  * the CPU time chromium's GPU process spends per frame: `--frames` slider moves, each waited
    for and followed by a 0.3 s rest, so one frame's work is all that runs; summed over the GPU
    process's threads (psutil), divided by the frames;
  * slider to frame over a stepwise drag of `--moves` moves (tools.browser.drag, 30 ms pauses),
    p50 / p99 / max, and how many frames' render took over 200 ms.
No GPU is used: headless chromium rasterises in software, on the cores the service shares.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import psutil

from service.settings import DEFAULT_MODEL

from bench._report import Report
from studies import results
from tools.browser import LLVMPIPE_FLAGS, SWIFTSHADER_FLAGS, drag, launch_chromium, open_viewer, \
    set_slider
from tools.loadtest import local_service


def gpu_process_cpu_s() -> float:
    """CPU seconds used so far by this process's descendant chromium GPU processes."""
    total = 0.0
    for child in psutil.Process().children(recursive=True):
        try:
            if "--type=gpu-process" in " ".join(child.cmdline()):
                times = child.cpu_times()
                total += times.user + times.system
        except psutil.Error:
            continue
    return total


def measure(url: str, flags: list[str], antialias: int, frames: int, moves: int) -> dict:
    with launch_chromium(flags) as browser, open_viewer(url, browser=browser, watch=False,
                                                        query=f"antialias={antialias}&scale=1") as (page, _):
        renderer = page.evaluate('__viewer.webgl')
        got = page.evaluate("__viewer.contextAntialias()")
        hi = float(page.evaluate("Number(document.getElementById('displacement').max)"))
        values = np.round(np.linspace(0.0, hi, 41), 2)
        time.sleep(1.0)
        start = gpu_process_cpu_s()
        for i in range(frames):
            set_slider(page, "displacement", float(values[(7 * i + 3) % 41]))
            time.sleep(0.3)
        per_frame_ms = 1000 * (gpu_process_cpu_s() - start) / frames
        drawn = drag(page, "displacement", values[np.arange(moves) % 41], pause_ms=30)
    ms = np.array([f["frameMs"] for f in drawn])
    render = np.array([f["renderMs"] for f in drawn])
    return {"renderer": renderer, "antialias": got, "gpu_ms": per_frame_ms, "p50": np.percentile(ms, 50),
            "p99": np.percentile(ms, 99), "max": ms.max(), "stalls": int((render > 200).sum())}


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m bench viewer-backends", description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    ap.add_argument("--frames", type=int, default=20, help="frames timed one at a time for the GPU process's CPU")
    ap.add_argument("--moves", type=int, default=300, help="stepwise drag for slider-to-frame")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    say = Report()
    with local_service("--model", str(args.model)) as url:
        say(f"{args.model}: GPU-process CPU per frame over {args.frames} frames; slider to frame over a "
              f"{args.moves}-move stepwise drag")
        say("| WebGL | multisampling | GPU process CPU per frame | slider to frame p50 / p99 / max "
            "| renders > 200 ms |")
        say("|---|---|---|---|---|")
        for flags in (SWIFTSHADER_FLAGS, LLVMPIPE_FLAGS):
            for antialias in (1, 0):
                r = measure(url, flags, antialias, args.frames, args.moves)
                name = "llvmpipe" if "llvmpipe" in r["renderer"] else "SwiftShader" if "SwiftShader" in r["renderer"] \
                    else r["renderer"]
                say(f"| {name} | {'on' if r['antialias'] else 'off'} | {r['gpu_ms']:.0f} ms | {r['p50']:.1f} / "
                      f"{r['p99']:.1f} / {r['max']:.0f} ms | {r['stalls']} |", flush=True)
    print(f"wrote {results.write('bench_viewer_backends', {'lines': say.lines}, publish=args.publish)}")
    return 0
