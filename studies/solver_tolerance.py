"""What the nonlinear solver's tolerances (solver.rtol, guide.contact_tol_mm) cost in time and buy in accuracy.

What the nonlinear solver's tolerances cost and buy: one displacement path per setting of
(solver.rtol, guide.contact_tol_mm), its time and work, and how far its fields are from a tight
reference's (rtol 1e-8, contact 0.001 mm) at the markers, the prostate surface and every node.

    MKL_NUM_THREADS=1 python -m studies solver-tolerance --mesh runs/p/mesh.npz [--publish]
    MKL_NUM_THREADS=1 python -m studies solver-tolerance --scene runs/patient_medium/scene.toml \
        --mesh runs/patient_medium/work/sweep/mesh.npz --name solver_tolerance_patient \
        --settings 1e-8:0.001 1e-6:0.005 1e-4:0.01

Each setting's path is written to --work as it finishes (its fields, npz) and the result
(runs/results/NAME.json; docs/results/ with --publish) is rewritten after each, so a stopped run
resumes at the next setting. The first setting is the reference. Run it alone: the times are the comparison.
"""

from __future__ import annotations

import argparse
import hashlib
from pathlib import Path

import numpy as np
from tqdm import tqdm

from contracts.cli import number
from fem_offline.geometry.mesh import load
from fem_offline.fe.problem import build_problem
from fem_offline.scene import load_scene
from studies import results
from studies.options import add_scene_flag, parser, tolerance_arg, with_tolerances
from studies.stepping import stepped_path

REFERENCE = "1e-8:0.001"
DEFAULT_SETTINGS = [REFERENCE, "1e-6:0.005", "1e-5:0.005", "1e-4:0.005", "1e-5:0.01", "1e-4:0.01", "1e-4:0.02"]


def distances(u: np.ndarray, ref: np.ndarray, sets: dict[str, np.ndarray]) -> dict:
    """Largest |u - ref| (mm) over the path's steps, per node set."""
    d = np.linalg.norm(u - ref, axis=-1)  # (n_steps, n_nodes)
    return {name: float(d[:, nodes].max()) for name, nodes in sets.items()}


def main(argv: list[str] | None = None) -> int:
    ap = parser("python -m studies solver-tolerance", __doc__)
    add_scene_flag(ap)
    ap.add_argument("--mesh", type=Path, required=True, help="mesh.npz of the scene (e.g. a sweep folder's)")
    ap.add_argument("--angle-deg", type=number("--angle-deg"), default=10.0)
    ap.add_argument("--to-mm", type=number("--to-mm", minimum=0.0), default=10.0)
    ap.add_argument("--settings", nargs="+", default=DEFAULT_SETTINGS,
                    help="rtol:contact_tol_mm pairs; the first is the reference")
    ap.add_argument("--name", default="solver_tolerance", help="the result's name (default solver_tolerance)")
    ap.add_argument("--work", type=Path, default=Path("runs/solver_tolerance"))
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    for setting in args.settings:
        try:
            tolerance_arg(setting)
        except argparse.ArgumentTypeError as exc:
            ap.error(f"--settings: {exc}")
    folder = results.DOCS_RESULTS if args.publish else results.RUNS_RESULTS

    scene, mesh = load_scene(args.scene), load(args.mesh)
    sets = {"markers": mesh.node_sets["markers"], "prostate_surface": mesh.node_sets["prostate_surface"],
            "nodes": np.arange(len(mesh.nodes))}
    key = hashlib.sha256(Path(args.mesh).read_bytes()).hexdigest()[:12] + f"_b{args.angle_deg:g}_d{args.to_mm:g}"
    args.work.mkdir(parents=True, exist_ok=True)
    result = {"scene": str(args.scene), "mesh": str(args.mesh), "n_tets": int(len(mesh.tets)),
              "angle_deg": args.angle_deg, "to_mm": args.to_mm, "reference": args.settings[0], "settings": {}}
    if (folder / f"{args.name}.json").exists():
        old = results.read(args.name, folder)
        if old.get("mesh") == result["mesh"] and old.get("angle_deg") == args.angle_deg:
            result["settings"] = old["settings"]
    ref = None
    for setting in tqdm(args.settings, desc="settings", unit="path"):
        rtol, tol = tolerance_arg(setting)
        cached = args.work / f"{key}_{rtol:g}_{tol:g}.npz"
        if cached.exists() and setting in result["settings"]:
            u = np.load(cached)["u"]
        else:
            print(f"rtol {rtol:g}, contact_tol_mm {tol:g}: {len(mesh.tets)} tets, beta {args.angle_deg:g} deg",
                  flush=True)
            problem = build_problem(with_tolerances(scene, rtol, tol), mesh)
            u, total = stepped_path(problem, args.angle_deg, args.to_mm)
            np.savez(cached, u=u)
            result["settings"][setting] = {"rtol": rtol, "contact_tol_mm": tol, **total}
        if ref is None:
            ref = u
        row = result["settings"][setting]
        row["vs_reference_mm"] = distances(u, ref, sets)
        results.write(args.name, result, publish=args.publish)
    base = result["settings"][args.settings[1]]["seconds"] if len(args.settings) > 1 else None
    print(f"\n{'rtol':>6} {'contact':>8} {'time s':>7} {'x':>5} {'Newton':>6} {'updates':>7} {'fact':>5}  "
          "max |u - u_ref| mm: markers / prostate surface / all nodes")
    for setting in args.settings:
        row = result["settings"][setting]
        if base:
            row["speedup_vs_first_nonreference"] = base / row["seconds"]
        v = row["vs_reference_mm"]
        print(f"{row['rtol']:6.0e} {row['contact_tol_mm']:8g} {row['seconds']:7.1f} "
              f"{base / row['seconds'] if base else 1:5.2f} {row['newton']:6d} {row['contact_updates']:7d} "
              f"{row['factorisations']:5d}  {v['markers']:.5f} / {v['prostate_surface']:.5f} / {v['nodes']:.5f}")
    print(f"wrote {results.write(args.name, result, publish=args.publish)}")
    return 0
