"""What accuracy costs in time: every row measured on this machine in one run -> docs/tradeoff.md + .png.

    python scripts/tradeoff.py --sweep runs/default --offgrid runs/default/offgrid [--out docs]

Rows (errors are max and p99 nodal errors in mm; times are medians of repeated runs):
  FE mesh fidelity  linear solve per snapshot vs error against the finest mesh, at probe points
                    inside the prostate, for beta = -10, 0, 10 deg at 10 mm
  FE physics        linear vs geometrically nonlinear: whole-sweep time vs their difference
  PCA rank          reconstruction and held-out error, full-mesh decode latency
  network           width/depth: held-out error, training time, decode latency
  precision/region  float32 vs float16 basis; full mesh vs a region
  FE vs surrogate   one query: FE solve vs decode (the paper: 11.1 min vs 0.04 s)
Held-out error = worst over the paper's five samples and the off-grid cases, float32 ONNX model.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from contracts.interpolate import PointLocator, interpolate
from contracts.model import onnx_session
from fem_offline.linear import linear_modes, min_det_f, superpose
from fem_offline.linsolve import AMG_MIN_DOFS
from fem_offline.meshing import mesh_for_scene
from fem_offline.problem import build_problem
from fem_offline.scene import load_scene
from fem_offline.validity import table_validity
from training.fit import PAPER_TEST_CASES, FitOptions, fit_surrogate, training_set
from training.snapshots import read_offgrid, read_sweep, snapshots_of

# the last is paper scale (225,938 tets, fem_offline/scenes/paper_scale.toml): solved by AMG-CG, the reference
MESH_SIZES = [(16.0, 6.0, 2.5), (12.0, 4.0, 2.0), (8.0, 2.7, 1.35), (6.0, 2.0, 1.0), (4.8, 1.6, 0.8), (3.5, 1.15, 0.58)]


def median_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def nodal(pred: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    e = np.linalg.norm(pred - ref, axis=-1).ravel()
    return float(e.max()), float(np.percentile(e, 99))


def row(group, setting, err, seconds, note="", **extra):
    return {"group": group, "setting": setting, "max_mm": err[0], "p99_mm": err[1], "seconds": seconds, "note": note, **extra}


def fe_mesh_rows(scene_path: Path) -> list[dict]:
    base = load_scene(scene_path)
    base = base.model_copy(update={"effects": base.effects.model_copy(update={"geometric_nonlinearity": False})})
    fields, meshes, times, solvers = [], [], [], []
    for mx, pr, gd in MESH_SIZES:
        scene = base.model_copy(update={"mesh": base.mesh.model_copy(update={"max_mm": mx, "prostate_mm": pr, "guide_mm": gd})})
        mesh = mesh_for_scene(scene)
        problem = build_problem(scene, mesh)
        runs = []
        for _ in range(3 if len(mesh.tets) < 30000 else 1):
            t0 = time.perf_counter()
            modes = linear_modes(problem)
            runs.append(time.perf_counter() - t0)
        t = float(np.median(runs))
        del problem
        fields.append(modes)
        meshes.append(mesh)
        times.append(t)
        solver = "AMG-CG" if 3 * len(mesh.nodes) >= AMG_MIN_DOFS else "PARDISO"
        solvers.append(solver)
        print(f"  mesh {mx}/{pr}/{gd} mm: {len(mesh.tets)} tets, linear solve ({solver}) {t:.2f} s", flush=True)
    # probes: the coarsest mesh's prostate nodes, which lie inside every finer mesh
    coarse = meshes[0]
    probes = coarse.nodes[np.unique(coarse.tets[coarse.tissue == coarse.tissue_names.index("prostate")])]

    def at_probes(mesh, field):
        tet, bary = PointLocator(mesh.nodes, mesh.tets).locate(probes)
        assert (tet >= 0).all()
        return interpolate(field[mesh.tets[tet]], bary)

    rows = []
    for beta in (-10.0, 0.0, 10.0):
        vals = [at_probes(mesh, superpose(modes, 10.0, beta)) for mesh, modes in zip(meshes, fields)]
        ref = vals[-1]
        for i, v in enumerate(vals[:-1]):
            rows.append((i, nodal(v, ref)))
    out = []
    for i, (mesh, t) in enumerate(zip(meshes[:-1], times[:-1])):
        errs = [e for j, e in rows if j == i]
        out.append(row("FE mesh (linear)", f"{len(mesh.tets)} tets", (max(e[0] for e in errs), max(e[1] for e in errs)), t,
                       f"sizes {MESH_SIZES[i]} mm; {solvers[i]}; vs {len(meshes[-1].tets)} tets", kind="query"))
    out.append(row("FE mesh (linear)", f"{len(meshes[-1].tets)} tets (reference)", (0.0, 0.0), times[-1],
                   f"paper scale; {solvers[-1]}; the reference", kind="reference"))
    return out


def physics_rows(sweep, scene_path: Path) -> list[dict]:
    scene = load_scene(scene_path)
    lin_scene = scene.model_copy(update={"effects": scene.effects.model_copy(update={"geometric_nonlinearity": False})})
    problem = build_problem(lin_scene, sweep.mesh)
    t_lin = median_time(lambda: linear_modes(problem), 3)
    modes = linear_modes(problem)
    lin = superpose(modes, sweep.inputs[:, 0], sweep.inputs[:, 1])
    err = nodal(lin, sweep.displacement)
    # where the linear answer stops being a deformation (det F <= 0 at a quadrature point): not a cheaper
    # stand-in for the nonlinear sweep beyond it (docs/linear_validity.md)
    grid = sweep.manifest.grid
    valid, _ = table_validity(grid.displacements_mm,
                              np.array([min_det_f(problem, modes, grid.displacements_mm, a) for a in grid.angles_deg]))
    # the wall time of the sweep's last run: a sweep run in one go states its whole time
    nl_seconds = sweep.manifest.wall_seconds_this_run
    return [row("FE physics", "linear, whole 840 sweep", err, t_lin,
                f"vs the nonlinear snapshots; inverts elements beyond {valid:g} mm", kind="sweep"),
            row("FE physics", "nonlinear, whole 840 sweep", (0.0, 0.0), nl_seconds, "sweep wall time from its manifest (last run)", kind="sweep")]


def decode_latency(model_bytes: bytes, nodes=None, repeat: int = 300):
    sess = onnx_session(model_bytes)
    feed = {"guide": np.array([[5.0, 2.0]], dtype=np.float32)}
    if nodes is not None:
        feed["nodes"] = np.asarray(nodes, dtype=np.int64)
    for _ in range(20):
        sess.run(None, feed)
    return median_time(lambda: sess.run(None, feed), repeat), sess


def held_out(sess, inputs, reference) -> tuple[float, float]:
    pred = np.concatenate([sess.run(None, {"guide": x[None].astype(np.float32)})[0] for x in inputs])
    return nodal(pred.astype(np.float64), reference)


def surrogate_rows(sweep, offgrid_inputs, offgrid_disp) -> list[dict]:
    s = snapshots_of(sweep)
    test, inputs, x = training_set(s, PAPER_TEST_CASES)
    ho_inputs = np.concatenate([s.inputs[test], offgrid_inputs])
    ho_ref = np.concatenate([s.displacement[test], offgrid_disp])
    rows = []
    for rank in (1, 2, 4, 8, 16, 24, 32, 48, 64):
        t0 = time.perf_counter()
        fitted = fit_surrogate(inputs, x, FitOptions(rank=rank, width=60, depth=1))
        t_train = time.perf_counter() - t0
        pca = fitted.pca
        d_ho = ho_inputs[:, :1, None]  # the model fits f = u / d (training/export.py)
        recon = d_ho * pca.decode(pca.encode((ho_ref / d_ho).reshape(len(ho_ref), -1))).reshape(ho_ref.shape)
        lat, sess = decode_latency(fitted.onnx_bytes())
        rows.append(row("PCA rank", f"rank {rank}", held_out(sess, ho_inputs, ho_ref), lat,
                        f"PCA alone {nodal(recon, ho_ref)[0]:.4f} mm; PCA + train {t_train:.1f} s", kind="query",
                        reconstruction_max_mm=nodal(recon, ho_ref)[0], train_seconds=t_train))
        print(f"  rank {rank}: held-out {rows[-1]['max_mm']:.4f} mm, decode {lat * 1e3:.3f} ms", flush=True)
    for width, depth in ((15, 1), (30, 1), (60, 1), (120, 1), (30, 2), (60, 2)):
        fitted = fit_surrogate(inputs, x, FitOptions(rank=32, width=width, depth=depth))
        t_train = fitted.info["seconds"]
        lat, sess = decode_latency(fitted.onnx_bytes())
        rows.append(row("network (rank 32)", f"{depth}x{width} tanh", held_out(sess, ho_inputs, ho_ref), lat,
                        f"train {t_train:.1f} s, {fitted.info['iterations']} L-BFGS iterations", kind="query",
                        train_seconds=t_train))
        print(f"  {depth}x{width}: held-out {rows[-1]['max_mm']:.4f} mm, train {t_train:.1f} s", flush=True)
        if (width, depth) == (60, 1):
            default = fitted
    for dtype, name in ((np.float32, "float32"), (np.float16, "float16")):
        model = default.onnx_bytes(dtype)
        lat, sess = decode_latency(model)
        rows.append(row("basis precision", f"{name} basis, full mesh", held_out(sess, ho_inputs, ho_ref), lat,
                        f"model.onnx {len(model) / 1e6:.1f} MB", kind="query"))
    model = default.onnx_bytes()
    full = held_out(decode_latency(model)[1], ho_inputs, ho_ref)
    for region in ("prostate_surface", "markers"):
        ids = sweep.mesh.node_sets[region]
        lat, sess = decode_latency(model, ids)
        pred = np.concatenate([sess.run(None, {"guide": xx[None].astype(np.float32), "nodes": ids})[0] for xx in ho_inputs])
        rows.append(row("region", f"{region} ({len(ids)} nodes)", nodal(pred.astype(np.float64), ho_ref[:, ids]), lat,
                        f"full mesh: {full[0]:.4f} mm; error over the region's nodes only", kind="region"))
    return rows


def fe_vs_surrogate(offgrid_files, default_latency: float) -> dict:
    seconds = []
    for f in offgrid_files:
        with np.load(f) as z:
            seconds.append(float(z["seconds"]))
    fe = float(np.median(seconds))
    return {"fe_seconds_median": fe, "fe_seconds_max": max(seconds), "surrogate_seconds": default_latency,
            "speedup": fe / default_latency, "paper_speedup": 11.1 * 60 / 0.04}


def pareto(points: list[tuple[float, float]]) -> list[int]:
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], np.inf
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def write_outputs(rows, versus, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    # The front is over answers for the whole mesh; region rows answer a smaller question and are only drawn.
    query = [r for r in rows if r["kind"] == "query" and r["max_mm"] > 0]
    regions = [r for r in rows if r["kind"] == "region"]
    pts = [(r["seconds"], r["max_mm"]) for r in query]
    front = set(pareto(pts))
    fig, ax = plt.subplots(figsize=(8, 5.5))
    groups = sorted({r["group"] for r in query}, key=lambda g: [r["group"] for r in query].index(g))
    for g, marker in zip(groups, "osD^vP*X"):
        idx = [i for i, r in enumerate(query) if r["group"] == g]
        ax.scatter([pts[i][0] for i in idx], [pts[i][1] for i in idx], marker=marker, label=g, s=40)
    ax.scatter([r["seconds"] for r in regions], [r["max_mm"] for r in regions], marker="x", c="grey", label="region only (not on the front)")
    for r in regions:
        ax.annotate(r["setting"], (r["seconds"], r["max_mm"]), fontsize=7, xytext=(4, -10), textcoords="offset points")
    fr = sorted(front, key=lambda i: pts[i][0])
    ax.plot([pts[i][0] for i in fr], [pts[i][1] for i in fr], "k--", lw=1, label="Pareto front")
    for i in fr:
        ax.annotate(query[i]["setting"], pts[i], fontsize=7, xytext=(4, 4), textcoords="offset points")
    ax.set(xscale="log", yscale="log", xlabel="time per query (s): FE solve or onnxruntime decode, median",
           ylabel="max nodal error (mm)", title="What accuracy costs in time (2 cores)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "tradeoff.png", dpi=120)
    lines = ["# Accuracy vs time", "", "Written by `python scripts/tradeoff.py --sweep runs/default --offgrid runs/default/offgrid`;",
             "every row was measured in the same run on the same machine (2 cores).", "",
             "| group | setting | max error (mm) | p99 error (mm) | time | note |", "|---|---|---|---|---|---|"]
    for r in rows:
        t = f"{r['seconds'] * 1e3:.3f} ms" if r["seconds"] < 1 else f"{r['seconds']:.2f} s"
        pf = " **(Pareto)**" if r in [query[i] for i in front] else ""
        lines.append(f"| {r['group']} | {r['setting']}{pf} | {r['max_mm']:.4f} | {r['p99_mm']:.5f} | {t} | {r['note']} |")
    lines += ["", f"**FE vs surrogate, one query**: FE nonlinear solve from rest (off-grid cases) median "
              f"{versus['fe_seconds_median']:.1f} s (max {versus['fe_seconds_max']:.1f} s); decode "
              f"{versus['surrogate_seconds'] * 1e3:.3f} ms: **{versus['speedup']:,.0f}x** faster. "
              f"The paper: 11.1 min vs 0.04 s = {versus['paper_speedup']:,.0f}x.", "",
              "Errors: FE mesh rows against the paper-scale mesh at the prostate's probe points (linear, 10 mm, "
              "beta = -10/0/10 deg); surrogate rows against the default mesh's FE snapshots (the paper's five "
              "held-out samples + the off-grid cases), all nodes, float32 ONNX model. Times: FE rows are one "
              "factorisation + solve (a linear snapshot: two unit solves; AMG-CG at paper scale, where PARDISO's factors do not fit "
              "in 24 GB), physics rows a whole sweep, surrogate rows one "
              "onnxruntime call (1 thread). Decode times within about 0.01 ms of each other are equal within "
              "this machine's noise, so Pareto marks among the rank-32 models mean little.", "", "![tradeoff](tradeoff.png)", ""]
    (out / "tradeoff.md").write_text("\n".join(lines))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sweep", type=Path, default=Path("runs/default"))
    ap.add_argument("--offgrid", type=Path, default=Path("runs/default/offgrid"))
    ap.add_argument("--scene", type=Path, default=Path("fem_offline/scenes/default.toml"))
    ap.add_argument("--out", type=Path, default=Path("docs"))
    ap.add_argument("--skip-fe-meshes", action="store_true", help="leave out the mesh-fidelity rows (the slowest part)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    sweep = read_sweep(args.sweep)
    files = sorted(p for p in args.offgrid.glob("offgrid_*.npz"))
    og_inputs, og_disp = read_offgrid(args.offgrid, len(sweep.mesh.nodes))
    print("surrogate rows ...", flush=True)
    rows = surrogate_rows(sweep, og_inputs, og_disp)
    print("physics rows ...", flush=True)
    rows = physics_rows(sweep, args.scene) + rows
    if not args.skip_fe_meshes:
        print("FE mesh rows ...", flush=True)
        rows = fe_mesh_rows(args.scene) + rows
    default = next(r for r in rows if r["setting"] == "1x60 tanh")
    versus = fe_vs_surrogate(files, default["seconds"])
    write_outputs(rows, versus, args.out)
    print(f"wrote {args.out / 'tradeoff.md'} and {args.out / 'tradeoff.png'} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
