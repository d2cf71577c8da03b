"""Time a material model's /predict: markers + 100 points and the full mesh, with std, in process and served.

    python -m bench materials [--model models/default] [--duration 5] [--repeat 500] [--publish]

With a material model (models/default is one), it is timed in process and then served over loopback HTTP on one
client with every tissue given with its std (the targets: p99 <= 5 ms for markers + 100 points, <= 40 ms for the
full mesh). For a model without material inputs, whose timing does not depend on its weights, a material model of
its mesh (a random PCA basis of --rank, a 1 x --width network, --tissues material inputs) is written to
runs/bench_materials_model and timed in process beside it. Each request is timed through
predict() (plan, locate, decode with std, interpolate) and the JSON reply built (replies.reply, its pieces
joined), p50 and p99 over --repeat calls on one thread: the service's work without HTTP. The same requests on
--model itself (no materials) are the baseline.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench._report import Report
from studies import results

OUT = Path("runs/bench_materials_model")


def material_model(model: Path, *, rank: int, width: int, tissues: int) -> Path:
    """A material model of `model`'s mesh with random weights (sizes only matter), in OUT."""
    from contracts.materials import MaterialInput, MaterialsInfo
    from contracts.model import read_model_folder, write_model_folder
    from training.material_graph import build_material_graph
    from training.pca import Pca

    base = read_model_folder(model)
    n3, rng = 3 * len(base.nodes), np.random.default_rng(0)
    pca = Pca(np.zeros(n3), np.linalg.qr(rng.normal(size=(n3, rank)))[0].T, np.ones(rank + 1))
    layers = [(0.1 * rng.normal(size=(2, width)), 0.1 * rng.normal(size=width)),
              (0.1 * rng.normal(size=(width, (1 + tissues) * rank)), np.zeros((1 + tissues) * rank))]
    names = ["prostate", "rectal_wall", "adipose", "bladder"][:tissues]
    info = MaterialsInfo(inputs=[MaterialInput(tissue=t, nominal_youngs_kpa=10.0, youngs_kpa_range=(8.0, 12.5),
                                               std_percent=21.0, poisson=0.495, density_kg_m3=1008.0) for t in names])
    write_model_folder(OUT, onnx_bytes=build_material_graph(layers, pca, tissues).SerializeToString(), mesh=base.mesh,
                       manifest=base.manifest.model_copy(update={"materials": info, "name": OUT.name}),
                       report="random weights: for timing only\n")
    return OUT


def timings(model: Path, repeat: int) -> dict[str, tuple[float, float]]:
    """p50 and p99 (ms) of predict() + the JSON reply for markers, markers + 100 points and the full mesh."""
    from service.info import model_info
    from service.model import Predictor, read_model_folder
    from service.predict.decode import predict
    from service.predict.replies import reply
    from service.predict.schemas import predict_request_model
    from service.settings import Settings

    folder = read_model_folder(model)
    predictor, request = Predictor(folder), predict_request_model(model_info(folder, Settings(model=model)), 200)
    prostate = folder.tets[np.flatnonzero(folder.mesh.tissue == folder.manifest.mesh.tissues.index("prostate"))[:100]]
    points = [*folder.nodes[prostate[:, :4]].mean(axis=1).tolist(), *folder.nodes[folder.regions["markers"]].tolist()]
    info = folder.manifest.materials  # every tissue at its nominal E with its std: the full uncertainty path
    extra = {"materials": {m.tissue: {"youngs_kpa": m.nominal_youngs_kpa, "std_percent": m.std_percent}
                           for m in info.inputs}} if info else {}
    out = {}
    for name, body in (("markers", {"region": "markers"}), ("markers + 100 points", {"points": points}),
                       ("full mesh", {})):
        req = request(displacement_mm=2.0, angle_deg=1.0, **body, **extra)

        def once():
            b"".join(reply(req, predict(predictor, req), fmt="json", model=folder.manifest.name).pieces)  # noqa: B023 -- run in this iteration only
        for _ in range(20):
            once()
        ms = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            once()
            ms.append((time.perf_counter() - t0) * 1e3)
        out[name] = (float(np.percentile(ms, 50)), float(np.percentile(ms, 99)))
    return out


def served(model: Path, duration_s: float) -> dict[str, dict]:
    """/predict over loopback HTTP on one client (tools/loadtest.py), every request with each tissue's E at its
    nominal value and the scene's std (the uncertainty on): markers + 100 points (JSON) and the full mesh (JSON and
    binary). The service runs with its defaults, access log off."""
    from tools import loadtest
    from service.model import read_model_folder

    folder = read_model_folder(model)
    prostate = folder.tets[np.flatnonzero(folder.mesh.tissue == folder.manifest.mesh.tissues.index("prostate"))[:100]]
    points = [*folder.nodes[prostate[:, :4]].mean(axis=1).round(3).tolist(),
              *folder.nodes[folder.regions["markers"]].round(3).tolist()]  # 100 points in the prostate + the markers
    materials = {m.tissue: {"youngs_kpa": m.nominal_youngs_kpa, "std_percent": m.std_percent}
                 for m in folder.manifest.materials.inputs}
    rows = {}
    with loadtest.local_service("--model", str(model), "--access-log", "off", wait_s=180) as url:
        for name, fmt, extra in (("markers + 100 points, JSON", "json", {"points": points}),
                                 ("full mesh, JSON", "json", {}), ("full mesh, binary", "binary", {})):
            rows[name] = loadtest.run(url, concurrency=1, duration_s=duration_s, fmt=fmt, warmup=20,
                                      extra={**extra, "materials": materials}).summary()
    return rows


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m bench materials", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=Path("models/default"), help="the model (and its mesh)")
    ap.add_argument("--rank", type=int, default=96, help="for a model without material inputs: the random "
                    "material model's basis rank")
    ap.add_argument("--width", type=int, default=120)
    ap.add_argument("--tissues", type=int, default=4, choices=range(1, 5))
    ap.add_argument("--repeat", type=int, default=500)
    ap.add_argument("--duration", type=float, default=5.0, help="seconds per served scenario (default 5)")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    say = Report()
    from contracts.model import read_manifest

    if read_manifest(args.model).materials is not None:
        runs = [("materials, with std", args.model)]
    else:
        made = material_model(args.model, rank=args.rank, width=args.width, tissues=args.tissues)
        runs = [("no materials", args.model), (f"{args.tissues} materials (random weights), with std", made)]
    for label, model in runs:
        for name, (p50, p99) in timings(model, args.repeat).items():
            say(f"{label}: {name}: p50 {p50:.2f} ms, p99 {p99:.2f} ms (predict + JSON reply, in process)")
    body = {"lines": say.lines, "in_process_model": str(runs[-1][1])}
    if len(runs) == 1:
        rows = served(args.model, args.duration)
        targets = {"markers + 100 points, JSON": 5.0, "full mesh, JSON": 40.0, "full mesh, binary": 40.0}
        for name, r in rows.items():
            met = "met" if r["p99_ms"] <= targets[name] else "NOT met"
            say(f"served, 1 client, {name}: p50 {r['p50_ms']:.2f} ms, p99 {r['p99_ms']:.2f} ms "
                f"(target p99 <= {targets[name]:g} ms: {met}; {r['requests']} requests, {r['errors']} errors)")
        body.update(served=rows, targets_p99_ms=targets, lines=say.lines)
    body["report_md"] = "# Material model latency\n\n" + "\n".join(f"- {line}" for line in say.lines) + "\n"
    print(f"wrote {results.write('bench_materials', body, publish=args.publish)}")
    return 0
