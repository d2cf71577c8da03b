"""What accuracy costs in time, end to end: mesh level x PCA rank x network on one Pareto front (result tradeoff).

    python -m studies tradeoff --sweep runs/default_graded --offgrid runs/default_graded/offgrid \\
        --convergence docs/results/convergence_taylor_hood.json --graded docs/results/graded_mesh.json \\
        --mesh-check runs/tiny_mesh_check [--publish]

The result tradeoff (runs/results/, or docs/results/ with --publish) holds every point, the levels,
the build estimates and the mesh check, with the Markdown report under "report_md" (the docs page
renders it) and the plot beside it as tradeoff.png.

Every configuration (mesh level L of the convergence study or a graded mesh judged against it, PCA rank r,
network w) is one point:
  error    end to end, per region: e_surrogate(r, w) + e_FE(L) (training/tradeoff.py states both):
           the model against the best converged estimate, not against its own mesh's FE. Regions:
           markers on every level; prostate surface and every node (in the table) on every level
           whose pointwise bound the JSON stores: all of them in a study analysed since the bound
           of a level under the three analysed is stored, fewer in older ones (training/tradeoff.py).
  latency  one onnxruntime call of the exported float32 graph, 1 thread, batch 1, median of repeats,
           all nodes (the plotted axis) and the prostate-surface subset (in the table). A level
           without a sweep is timed on a graph of the same shapes with a random basis.
  build    the 840-case sweep's wall time on WORKERS processes: estimated for every level as
           ceil(paths / workers) x that level's full-push solve time in the convergence JSON
           (mirror symmetry: the sweep solves the beta >= 0 paths only), the measured sweep beside
           it for the sweep's level; plus the PCA + training time of (r, w).
Assumption: e_surrogate is measured on the sweep's level only (the only 840-case sweep) and added
to every level's e_FE. --mesh-check fits the same way on the tiny scene at two mesh sizes (nonlinear
1 mm x 2 deg sweeps, built there if missing: about 4 min of FE once) to show how much it moves.
Held-out cases: the paper's five Table 3 samples and the off-grid cases inside the sweep's valid envelope.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

# One thread for numpy and torch, set before they load: the fits' round-off (and so where L-BFGS stops)
# then does not depend on the machine's cores or load, and a shared 2-core machine is not oversubscribed
# (2 threads there made one fit up to 40x slower). The decode timings use 1 onnxruntime thread anyway.
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from contracts.cli import number  # noqa: E402
from contracts.model import onnx_session, read_manifest  # noqa: E402
from studies import results  # noqa: E402
from studies.options import json_ready  # noqa: E402
from training.fit import PAPER_TEST_CASES, FitOptions, fit_surrogate, region_errors, training_set  # noqa: E402
from training.snapshots import read_offgrid, read_sweep, valid_part  # noqa: E402
from training.tradeoff import (decode_seconds, end_to_end, graded_levels, level_errors, makespan,  # noqa: E402
                               pareto_mask, shaped_graph, solved_path_seconds, sweep_estimate)

RANKS = (8, 16, 24, 32, 40, 48, 64)
NETWORKS = ((30, 1), (60, 1), (120, 1), (160, 1), (60, 2))  # (width, depth)
DEFAULT = (64, 120, 1)  # models/default: rank, width, depth
WORKERS = 2  # the sweep's default process count, as the measured sweep ran
MESH_CHECK_SCALES = (1.69, 1.0)
MESH_CHECK_RANKS = (8, 16, 24)
# on the 1 mm x 2 deg grid, inside its valid 0-7 mm
MESH_CHECK_HELD_OUT = ((6.0, -6.0), (4.0, -4.0), (5.0, -2.0), (2.0, 0.0), (3.0, 2.0))
SHOWN = ("markers", "prostate_surface")


def held_out(sweep, offgrid: Path, test_cases):
    """(training inputs, rows, held-out inputs, held-out displacements) inside the sweep's valid envelope."""
    data, envelope, _ = valid_part(sweep)
    test, inputs, rows = training_set(data, test_cases)
    h_in, h_ref = data.inputs[test], data.displacement[test]
    if offgrid is not None:
        og_in, og_ref = read_offgrid(offgrid, len(sweep.mesh.nodes))
        inside = np.array([envelope.contains(*x) for x in og_in], dtype=bool)
        h_in, h_ref = np.concatenate([h_in, og_in[inside]]), np.concatenate([h_ref, og_ref[inside]])
    return inputs, rows, h_in, h_ref


def fit_configs(sweep, offgrid, ranks, networks, test_cases=PAPER_TEST_CASES) -> list[dict]:
    """Fit every (rank, network) on the sweep; surrogate error per region on the held-out cases."""
    inputs, rows, h_in, h_ref = held_out(sweep, offgrid, test_cases)
    out = []
    for rank in ranks:
        for width, depth in networks:
            t0 = time.perf_counter()
            fitted = fit_surrogate(inputs, rows, FitOptions(rank=rank, width=width, depth=depth))
            train_s = time.perf_counter() - t0
            onnx = fitted.onnx_bytes()
            err = region_errors(onnx_session(onnx), h_in, h_ref, sweep.mesh.node_sets)
            out.append({"rank": rank, "width": width, "depth": depth, "surrogate_mm": err, "train_s": train_s,
                        "iterations": fitted.info["iterations"], "layers": fitted.layers, "onnx": onnx,
                        "n_held_out": len(h_in)})
            print(f"  rank {rank:2d} {depth}x{width:<3d}: markers {err['markers']:.5f} mm, surface "
                  f"{err['prostate_surface']:.5f} mm, {fitted.info['iterations']} iterations, {train_s:.1f} s",
                  flush=True)
    return out


def points(configs, levels, sweep_level, sweep, repeat: int) -> list[dict]:
    """One point per (level, configuration): end-to-end error and decode latency (full mesh, surface subset)."""
    surface = np.asarray(sweep.mesh.node_sets["prostate_surface"])
    pts = []
    for lv in levels:
        own = lv is sweep_level
        # the surface's node count on a level without a mesh here: scaled as an area, n_nodes^(2/3)
        k = len(surface) if own else int(round(len(surface) * (lv.n_nodes / sweep_level.n_nodes) ** (2 / 3)))
        for c in configs:
            model = c["onnx"] if own else shaped_graph(c["layers"], lv.n_nodes)
            pts.append({"level": lv.label, "n_tets": lv.n_tets, "n_nodes": lv.n_nodes, "rank": c["rank"],
                        "net": f"{c['depth']}x{c['width']}", "surrogate_mm": c["surrogate_mm"], "fe_mm": lv.fe_mm,
                        "e2e_mm": end_to_end(c["surrogate_mm"], lv.fe_mm), "train_s": c["train_s"],
                        "iterations": c["iterations"], "latency_s": decode_seconds(model, repeat=repeat),
                        "surface_latency_s": decode_seconds(model, surface if own else np.arange(k), repeat=repeat),
                        "surface_nodes": k, "surface_nodes_estimated": not own,
                        "default": own and (c["rank"], c["width"], c["depth"]) == DEFAULT})
        print(f"  {lv.label} ({lv.n_tets} tets): timed {len(configs)} graphs", flush=True)
    for region in SHOWN:
        idx = [i for i, p in enumerate(pts) if region in p["e2e_mm"]]
        mask = pareto_mask([pts[i]["latency_s"] for i in idx], [pts[i]["e2e_mm"][region] for i in idx])
        for i, m in zip(idx, mask):
            pts[i][f"pareto_{region}"] = bool(m)
    return pts


def tiny_sweeps(folder: Path) -> list[Path]:
    """The tiny scene's nonlinear 1 mm x 2 deg sweep at each MESH_CHECK_SCALES mesh size (resumable;
    built if missing)."""
    from studies.convergence import scaled_scene
    from fem_offline.scene import load_scene
    from fem_offline.sweep import run_sweep

    base = load_scene(Path("fem_offline/scenes/tiny.toml"), sweep={
        "displacement_step_mm": 1.0, "displacement_max_mm": 10.0, "angle_min_deg": -10.0, "angle_max_deg": 10.0,
        "angle_step_deg": 2.0})
    out = []
    for scale in MESH_CHECK_SCALES:
        path = folder / f"{scale:g}"
        manifest = run_sweep(scaled_scene(base, scale), path, workers=WORKERS)
        if manifest.n_done != manifest.n_expected:
            raise SystemExit(f"--mesh-check: {path} has {manifest.n_done} of {manifest.n_expected} snapshots: "
                             f"{manifest.errors}")
        out.append(path)
    return out


def mesh_check(folder: Path) -> list[dict]:
    """Surrogate errors of the same fits on the tiny scene at each mesh size:
    how much e_surrogate depends on the mesh."""
    rows = []
    for path in tiny_sweeps(folder):
        sweep = read_sweep(path)
        print(f"mesh check: {path} ({len(sweep.mesh.tets)} tets)", flush=True)
        for c in fit_configs(sweep, None, MESH_CHECK_RANKS, ((60, 1),), MESH_CHECK_HELD_OUT):
            rows.append({"folder": str(path), "n_tets": len(sweep.mesh.tets), "rank": c["rank"],
                         "surrogate_mm": c["surrogate_mm"]})
    return rows


def ms(seconds: float) -> str:
    return f"{seconds * 1e3:.3f} ms"


def duration(seconds: float) -> str:
    return f"{seconds:.0f} s ({seconds / 60:.1f} min)"


def figure(pts, levels, build, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(17, 5.5))
    order = [lv.label for lv in sorted(levels, key=lambda lv: lv.n_tets)]
    colours = dict(zip(order, ("tab:red", "tab:orange", "tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:pink",
                               "tab:olive", "tab:cyan", "tab:gray")))
    shapes = dict(zip([f"{d}x{w}" for w, d in NETWORKS], "osDv^"))
    tets = {lv.label: lv.n_tets for lv in levels}
    for ax, region in zip(axes[:2], SHOWN):
        sub = [p for p in pts if region in p["e2e_mm"]]
        for p in sub:
            ax.scatter(p["latency_s"] * 1e3, p["e2e_mm"][region], c=colours[p["level"]], marker=shapes[p["net"]],
                       s=12 + 2 * p["rank"], alpha=0.75, edgecolors="k" if p[f"pareto_{region}"] else "none")
        front = sorted((p for p in sub if p[f"pareto_{region}"]), key=lambda p: p["latency_s"])
        ax.step([p["latency_s"] * 1e3 for p in front], [p["e2e_mm"][region] for p in front], "k--", lw=1, where="post",
                label="Pareto front")
        last = None
        for p in front:  # label the front where it moves on: a new level or 1.3x the last label's latency
            if last is None or p["level"] != last["level"] or p["latency_s"] > 1.3 * last["latency_s"]:
                ax.annotate(f"r{p['rank']} {p['net']}", (p["latency_s"] * 1e3, p["e2e_mm"][region]), fontsize=7,
                            xytext=(3, 4), textcoords="offset points")
                last = p
        d = next((p for p in sub if p["default"]), None)
        if d:
            ax.scatter(d["latency_s"] * 1e3, d["e2e_mm"][region], marker="*", s=220, facecolors="none", edgecolors="k",
                       label=f"models/default (rank {DEFAULT[0]}, 1x{DEFAULT[1]})")
        ax.set(xscale="log", xlabel="online latency: one decode, all nodes (ms, onnxruntime, 1 thread, median)",
               ylabel=f"end-to-end error at the {region.replace('_', ' ')} (mm, max)",
               title=f"{region.replace('_', ' ')}: surrogate + FE vs the converged estimate")
        ax.grid(True, which="both", alpha=0.3)
    for level, col in colours.items():
        axes[0].scatter([], [], c=col, label=f"{tets[level]:,} tets ({level})")
    for net, m in shapes.items():
        axes[0].scatter([], [], c="grey", marker=m, label=f"network {net}")
    axes[0].legend(fontsize=7, title="marker size: PCA rank 8..48", title_fontsize=7)
    axes[1].legend(fontsize=7)
    ax = axes[2]
    for p in pts:
        ax.scatter(build[p["level"]]["estimate_s"] + p["train_s"], p["e2e_mm"]["markers"], c=colours[p["level"]],
                   marker=shapes[p["net"]], s=12 + 2 * p["rank"], alpha=0.75)
    for level, b in build.items():
        if b.get("measured_s") is not None:
            ax.axvline(b["measured_s"], color=colours[level], ls=":", lw=1,
                       label=f"measured sweep, {tets[level]:,} tets")
    ax.set(xlabel="offline build (s): sweep (estimated) + PCA and training",
           ylabel="end-to-end error at the markers (mm, max)", title="what a build costs offline (2 workers)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "tradeoff.png", dpi=110)
    plt.close(fig)


def fmt(x) -> str:
    return "—" if x is None else f"{x:.4f}"


def pareto_lines(pts, region) -> list[str]:
    front = sorted((p for p in pts if p.get(f"pareto_{region}")), key=lambda p: p["latency_s"])
    return [f"| {p['n_tets']:,} | {p['rank']} | {p['net']} | {ms(p['latency_s'])} | {p['e2e_mm'][region]:.4f} | "
            f"{p['surrogate_mm'][region]:.5f} | {p['fe_mm'][region]:.4f} |" for p in front]


def level_lines(levels, build, sweep_level) -> list[str]:
    lines = ["| mesh | nodes | e_FE markers | e_FE prostate surface | e_FE every node | full-push solve (one path) "
             "| sweep, estimated | sweep, measured |", "|---|---|---|---|---|---|---|---|"]
    for lv in levels:
        b = build[lv.label]
        own = " (the sweep's)" if lv is sweep_level else ""
        lines.append(f"| {lv.n_tets:,} tets, {lv.label}{own} | {lv.n_nodes:,} | {fmt(lv.fe_mm.get('markers'))} | "
                     f"{fmt(lv.fe_mm.get('prostate_surface'))} | {fmt(lv.fe_mm.get('all_nodes'))} | "
                     f"{lv.path_seconds:.0f} s | {duration(b['estimate_s'])} | "
                     f"{duration(b['measured_s']) if b['measured_s'] else '—'} |")
    return lines


def point_lines(pts) -> list[str]:
    lines = ["| mesh (tets) | rank | net | surrogate: markers / surface / every node (mm) | end to end: markers / "
             "surface / every node (mm) | decode, all nodes | decode, surface (nodes) | PCA + train | L-BFGS "
             "iterations | Pareto |", "|---|---|---|---|---|---|---|---|---|---|"]
    for p in pts:
        s, e = p["surrogate_mm"], p["e2e_mm"]
        marks = ([r.replace("prostate_", "") for r in SHOWN if p.get(f"pareto_{r}")]
                 + (["default"] if p["default"] else []))
        est = " est." if p["surface_nodes_estimated"] else ""
        lines.append(f"| {p['n_tets']:,} | {p['rank']} | {p['net']} | {s['markers']:.5f} / {s['prostate_surface']:.5f} "
                     f"/ {s['all_nodes']:.5f} | {fmt(e.get('markers'))} / {fmt(e.get('prostate_surface'))} / "
                     f"{fmt(e.get('all_nodes'))} | {ms(p['latency_s'])} | {ms(p['surface_latency_s'])} "
                     f"({p['surface_nodes']}{est}) | {p['train_s']:.1f} s | {p['iterations']} | {', '.join(marks)} |")
    return lines


def check_lines(rows) -> list[str]:
    if not rows:
        return ["Not run (no --mesh-check)."]
    lines = ["| tiny mesh | rank (1x60) | surrogate: markers | prostate surface | every node (mm) |",
             "|---|---|---|---|---|"]
    for r in rows:
        s = r["surrogate_mm"]
        lines.append(f"| {r['n_tets']:,} tets | {r['rank']} | {s['markers']:.5f} | {s['prostate_surface']:.5f} | "
                     f"{s['all_nodes']:.5f} |")
    return lines


def committed_line(model: Path, sweep_level) -> list[str]:
    """The committed model of the default configuration, if it was fitted on the sweep's mesh:
    its own surrogate errors."""
    if not (model / "manifest.json").is_file():
        return []
    m = read_manifest(model)
    if ((m.fit.rank, m.fit.width, m.fit.depth) != DEFAULT
            or (m.mesh.n_tets, m.mesh.n_nodes) != (sweep_level.n_tets, sweep_level.n_nodes)):
        return []
    s = {k: r.surrogate_mm for k, r in m.accuracy.regions.items()}
    e = end_to_end(s, sweep_level.fe_mm)
    return [f"The committed `{model}` (the same configuration, trained to {m.network.iterations} L-BFGS iterations "
            f"when it was built) errs {s['markers']:.5f} / {s['prostate_surface']:.5f} / {s['all_nodes']:.5f} mm "
            f"as a surrogate: end to end {e['markers']:.3f} / {e['prostate_surface']:.3f} / {e['all_nodes']:.3f} mm "
            "with the FE errors above. The two differ in where L-BFGS stopped (see \"Every configuration\").", ""]


def markdown(pts, levels, sweep_level, build, checks, fe_query, meta) -> str:
    d = next(p for p in pts if p["default"])
    speedup = float(f"{fe_query['median'] / d['latency_s']:.2g}")  # two significant digits: the decode time is noisy
    lines = [
        "# Accuracy vs time, end to end", "",
        f"Measured in {meta['seconds']:.0f} s (latencies are medians; on a shared machine differences of about "
        "0.01 ms are noise).", "",
        "Each point is a configuration: a mesh level L of the grid-convergence study "
        f"([{meta['convergence']}]({Path(meta['convergence']).name})) or a mesh graded where the error is, judged "
        f"against the same study ({meta['graded']}), a PCA rank and a network. Its error is **end "
        "to end**: the surrogate's error against its own mesh's FE plus that mesh's FE error against the best "
        "converged estimate (`training/tradeoff.py`), max over the region's points and the cases. Its time is the "
        "**online latency**: one onnxruntime call of the exported float32 graph (1 thread, batch 1, median). The "
        "offline build cost is the third panel.", "",
        "* **FE error of a level** (from the convergence JSON): the finest level's GCI band (Fs 1.25); a coarser "
        "level's |u_L − u_finest| plus the finest's band, pointwise at the markers. The JSON keeps the prostate "
        "surface and every node only as summaries of the three analysed levels (a coarser level's pointwise bound, max "
        "over the points; studies analysed before the coarse bound was stored give the two finest), so the surface "
        "panel has those levels only, and every node the same (table). A graded mesh (`python -m studies "
        "graded-mesh`): the same bound, |u − u_finest| plus the finest's band, at the study's markers, "
        "surface points and nodes.",
        f"* **Surrogate error**: fitted and measured on the {sweep_level.n_tets:,}-tet sweep ({meta['sweep']}, the "
        f"only 840-case sweep), held out: the paper's five Table 3 samples and {meta['n_offgrid']} off-grid cases "
        f"({meta['n_held_out']} cases). **Assumed**: the same (rank, network) errs as much on "
        "every level's sweep, so the measured value is added to every level's FE error. The mesh check below tests it "
        "on the tiny scene.",
        "* **Latency of a level without a sweep**: the same network exported (`training/export.py`) with a random "
        "basis of that level's shape; onnxruntime's work depends on the shapes only. The surface subset's node count "
        f"there is estimated (the sweep's {meta['surface_nodes']} scaled by nodes^(2/3), 'est.').",
        f"* **Build cost**: the 840-case sweep on {WORKERS} workers solves {meta['n_paths']} paths (β ≥ 0; β < 0 is "
        "mirrored). Estimated for every level as ceil(paths / workers) × that level's full-push solve time in the "
        "convergence JSON (mean of its 10 mm cases, solved from rest); the sweep's own level is also measured: its "
        "per-path solve seconds (manifest) scheduled on the workers. Training (PCA + network) is measured per point.",
        "",
        "## The default configuration", "",
        f"`models/default` (rank {DEFAULT[0]}, {DEFAULT[2]}x{DEFAULT[1]}, {sweep_level.n_tets:,} tets): "
        f"**{d['e2e_mm']['markers']:.3f} mm at the markers, {d['e2e_mm']['prostate_surface']:.3f} mm on the prostate "
        f"surface, {d['e2e_mm']['all_nodes']:.3f} mm at every node**, end to end; of which the surrogate "
        f"{d['surrogate_mm']['markers']:.5f} / {d['surrogate_mm']['prostate_surface']:.5f} / "
        f"{d['surrogate_mm']['all_nodes']:.5f} mm. Decode {ms(d['latency_s'])} (all nodes), "
        f"{ms(d['surface_latency_s'])} (surface); {d['iterations']} L-BFGS "
        "iterations in this run.", "", *meta["committed"],
        "## Mesh levels", "", *level_lines(levels, build, sweep_level), "",
        "At the sweep's level the estimate is "
        f"{build[sweep_level.label]['estimate_s'] / build[sweep_level.label]['measured_s']:.2f}x "
        "the measured sweep: the study's solve times (one path from rest, at the study's load step, which may be "
        "larger than the sweep's 0.25 mm, on a machine shared with other jobs) are a rough scale for the others.", "",
        "## Pareto points", "",
        "Markers (every level):", "", "| mesh (tets) | rank | net | decode | end to end (mm) | surrogate | FE |",
        "|---|---|---|---|---|---|---|", *pareto_lines(pts, "markers"), "",
        "Prostate surface (the levels the study analysed):", "",
        "| mesh (tets) | rank | net | decode | end to end (mm) | surrogate | FE |",
        "|---|---|---|---|---|---|---|", *pareto_lines(pts, "prostate_surface"), "",
        "Decode times within about 0.01–0.02 ms of each other are equal within this machine's noise, so the order of "
        "neighbouring Pareto points is not significant.", "",
        "## Does the surrogate's error depend on the mesh?", "",
        "The same fits (1x60, ranks below) on the tiny scene's nonlinear sweep (1 mm × 2°, 110 snapshots, held out "
        f"{', '.join(f'{a:g}/{b:g}' for a, b in MESH_CHECK_HELD_OUT)} mm/°) at two mesh sizes (sizes × "
        f"{' and × '.join(f'{s:g}' for s in MESH_CHECK_SCALES)}):", "", *check_lines(checks), "",
        "## FE solved online instead", "",
        "Solving the FE per query removes the surrogate's share but costs the full-push solve time: "
        + ", ".join(f"{lv.path_seconds:.0f} s on {lv.n_tets:,} tets "
                    f"(error {fmt(lv.fe_mm.get('markers'))} mm at the markers)"
                    for lv in levels)
        + f". The off-grid cases on the sweep's mesh took {fe_query['median']:.0f} s median (max {fe_query['max']:.0f} "
        f"s) from rest; the default decode {ms(d['latency_s'])}: about {speedup:,.0f}x faster, "
        "for an end-to-end error larger by the surrogate's share above. The paper: 11.1 min vs 0.04 s.", "",
        "## Left out of this study", "",
        "* **The linear model**: it is cut where it turns elements inside out (the glued linear sweep of "
        "default.toml's mesh from 5.5 mm, counting det F between the quadrature points, "
        "[linear_validity.json](linear_validity.json); `fem_offline/fe/validity.py`), so a linear model answers only "
        "part of the 0–10 mm envelope of these points, and is not a point on this front.",
        "* **Finer meshes than the study's finest** (the earlier linear rows up to paper scale): their error against "
        "the converged estimate is not known until the convergence study has them; FE solves at those sizes are not "
        "rerun here.",
        "* **float16 basis and node subsets other than the surface**: not configurations of the end-to-end error.", "",
        "## Every configuration", "",
        "One fit per configuration (seed 0, up to 1000 L-BFGS iterations, as `training fit`). A run that stops after "
        "fewer than about 100 iterations met L-BFGS's change tolerance early (`training/network.py` takes that as "
        "converged); its error can be several times that of a run that went on, and which runs stop depends on "
        "round-off (the thread count changes it). So neighbouring networks are ranked partly by the optimiser's luck; "
        "the surrogate's share of the end-to-end error stays small either way.", "", *point_lines(pts), "",
        "![tradeoff](tradeoff.png)", ""]
    return "\n".join(lines)


def fe_query_seconds(offgrid: Path) -> dict:
    seconds = []
    for f in sorted(offgrid.glob("offgrid_*.npz")):
        with np.load(f) as z:
            seconds.append(float(z["seconds"]))
    return {"median": float(np.median(seconds)), "max": max(seconds)}


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies tradeoff", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sweep", type=Path, default=Path("runs/default"), help="the 840-case sweep on one study level")
    ap.add_argument("--offgrid", type=Path, default=Path("runs/default/offgrid"))
    ap.add_argument("--convergence", type=Path, default=Path("runs/results/convergence_taylor_hood.json"),
                    help="`python -m studies convergence-study`'s result (e.g. "
                         "docs/results/convergence_taylor_hood.json)")
    ap.add_argument("--graded", type=Path, help="`python -m studies graded-mesh`'s result: graded meshes judged "
                    "against the same study, as more levels (e.g. docs/results/graded_mesh.json)")
    ap.add_argument("--mesh-check", type=Path,
                    help="folder of the tiny scene's sweeps for the mesh check (built if missing)")
    ap.add_argument("--model", type=Path, default=Path("models/default"),
                    help="the committed model of the default configuration, quoted beside this run's fit")
    ap.add_argument("--repeat", type=number("--repeat", int, minimum=1), default=200,
                    help="timed onnxruntime calls per graph (median)")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    sweep = read_sweep(args.sweep)
    levels = level_errors(json.loads(args.convergence.read_text()))
    if args.graded:
        try:
            skipped: list[str] = []
            levels = sorted(levels + graded_levels(json.loads(args.graded.read_text()), skipped),
                            key=lambda lv: lv.n_tets)
        except (ValueError, KeyError) as exc:
            raise SystemExit(f"--graded: {args.graded}: {exc}") from None
        if skipped:
            print(f"--graded: left out (judged on fewer cases than the others): {', '.join(skipped)}", flush=True)
    own = (len(sweep.mesh.tets), len(sweep.mesh.nodes))
    sweep_level = next((lv for lv in levels if (lv.n_tets, lv.n_nodes) == own), None)
    if sweep_level is None:
        raise SystemExit(f"--convergence/--graded: no level of {args.convergence} or graded mesh has the sweep's "
                         f"{own[0]} tets and {own[1]} nodes")
    checks = mesh_check(args.mesh_check) if args.mesh_check else []
    print("fits on the sweep ...", flush=True)
    configs = fit_configs(sweep, args.offgrid, RANKS, NETWORKS)
    print("decode latency ...", flush=True)
    pts = points(configs, levels, sweep_level, sweep, args.repeat)
    paths = solved_path_seconds(sweep.manifest)
    build = {lv.label: {"estimate_s": sweep_estimate(lv.path_seconds, len(paths), WORKERS),
                        "measured_s": makespan(paths, WORKERS) if lv is sweep_level else None} for lv in levels}
    out = results.DOCS_RESULTS if args.publish else results.RUNS_RESULTS
    out.mkdir(parents=True, exist_ok=True)
    figure(pts, levels, build, out)
    graded = f"[{args.graded}]({args.graded.name})" if args.graded else "none in this run"
    meta = {"convergence": str(args.convergence),
            "graded": graded,
            "sweep": str(args.sweep), "surface_nodes": len(sweep.mesh.node_sets["prostate_surface"]),
            "n_paths": len(paths), "n_held_out": configs[0]["n_held_out"],
            "n_offgrid": configs[0]["n_held_out"] - len(PAPER_TEST_CASES),
            "committed": committed_line(args.model, sweep_level), "seconds": time.perf_counter() - t0}
    fe_query = fe_query_seconds(args.offgrid)
    report = markdown(pts, levels, sweep_level, build, checks, fe_query, meta)
    path = results.write("tradeoff", json_ready({
        "sweep": str(args.sweep), "convergence": str(args.convergence),
        "graded": str(args.graded) if args.graded else None,
        "levels": [vars(lv) | {"build": build[lv.label]} for lv in levels], "sweep_level": sweep_level.label,
        "points": pts, "mesh_check": checks, "fe_query_s": fe_query,
        "report_md": report}), publish=args.publish)
    d = next(p for p in pts if p["default"])
    print(f"default (rank {DEFAULT[0]}, {DEFAULT[2]}x{DEFAULT[1]}, {d['n_tets']} tets): end to end "
          f"{d['e2e_mm']['markers']:.4f} mm at the markers, {d['e2e_mm']['prostate_surface']:.4f} mm at the surface; "
          f"decode {ms(d['latency_s'])}")
    for region in SHOWN:
        front = sorted((p for p in pts if p.get(f"pareto_{region}")), key=lambda p: p["latency_s"])
        print(f"Pareto ({region}): " + "; ".join(f"{p['n_tets']} tets r{p['rank']} {p['net']} {ms(p['latency_s'])} "
                                                 f"{p['e2e_mm'][region]:.4f} mm" for p in front))
    print(f"wrote {path} and {out / 'tradeoff.png'} in {time.perf_counter() - t0:.0f} s")
    return 0
