"""Slider-to-frame latency of the viewer in headless chromium (SwiftShader WebGL), and what each way of fetching a frame costs.

    python scripts/bench_viewer.py [--model models/default] [--moves 200]

Starts `python -m service` on a loopback port, opens /viewer, drags the displacement slider
through `--moves` values from inside the page (service.browser.drag: each step fires `input`,
waits for its frame, pauses 30 ms) and prints the page's own figures: input event to WebGL
finished (lastFrameMs) and the /predict replies alone (lastFetchMs) and the render (lastRenderMs). Then, in the page, times
the ways a frame could be fetched: the viewer's requests, the region cover, one request per
drawn tissue, and the whole mesh in one request.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from service.browser import drag, open_viewer
from service.loadtest import local_service
from service.model import read_model_folder
from service.settings import DEFAULT_MODEL
from service.viewer import region_cover

# Times `n` parallel-fetch rounds of the given /predict bodies in the page; returns the ms of each.
FETCH_ROUNDS = """async ([bodies, n]) => { const out = [];
  for (let i = 0; i < n; i++) {
    const t = performance.now();
    await Promise.all(bodies.map((b) => fetch('/predict', { method: 'POST', body: JSON.stringify({ ...b, angle_deg: i % 7 }),
      headers: { 'content-type': 'application/json', accept: 'application/octet-stream' } }).then((r) => r.arrayBuffer())));
    out.push(performance.now() - t);
  }
  return out; }"""


def _summary(ms) -> str:
    ms = np.asarray(ms)
    return f"p50 {np.percentile(ms, 50):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms, max {ms.max():.1f} ms"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    ap.add_argument("--moves", type=int, default=200)
    args = ap.parse_args()
    folder = read_model_folder(args.model)
    with local_service("--model", str(args.model)) as url, open_viewer(url, watch=False) as (page, _):
        hi = page.evaluate("Number(document.getElementById('displacement').max)")
        values = np.round(np.linspace(0.0, hi, 41), 2)
        frames = drag(page, "displacement", values[np.arange(args.moves) % len(values)])
        scene = page.evaluate("fetch('/viewer/scene.json').then((r) => r.json())")
        tissues = [t["name"] for t in scene["tissues"]]
        print(f"{scene['model']}: {args.moves} slider moves, {len(scene['regions'])} /predict requests a frame "
              f"({', '.join(r or 'whole mesh' for r in scene['regions'])})")
        print(f"  slider to frame (input event to WebGL finished): {_summary([f['frameMs'] for f in frames])}")
        print(f"  of which the /predict replies: {_summary([f['fetchMs'] for f in frames])}")
        print(f"  of which the render (three.js + gl.finish): {_summary([f['renderMs'] for f in frames])}")
        case = {"displacement_mm": hi / 2}
        cover = region_cover(folder, np.unique(np.concatenate([folder.regions["markers"], *(s.ravel() for s in folder.surfaces.values())])))
        for label, bodies in (("the viewer's requests", [{**case, **({} if r is None else {"region": r})}
                                                          for r in scene["regions"]]),
                              ("region cover", [{**case, "region": r} for r in cover]),
                              ("one request per drawn tissue", [{**case, "region": t} for t in [*tissues, "markers"]]),
                              ("whole mesh, one request", [case])):
            print(f"  fetch only, {label}, {len(bodies)} requests: {_summary(page.evaluate(FETCH_ROUNDS, [bodies, 50]))}")


if __name__ == "__main__":
    main()
