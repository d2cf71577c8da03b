"""What the nonlinear solver's tolerances cost and buy: one displacement path per setting of
(solver.rtol, guide.contact_tol_mm), its time and work, and how far its fields are from a tight
reference's (rtol 1e-8, contact 0.001 mm) at the markers, the prostate surface and every node.

    MKL_NUM_THREADS=1 python scripts/solver_tolerance.py --mesh runs/p/mesh.npz --out docs/solver_tolerance.json
    MKL_NUM_THREADS=1 python scripts/solver_tolerance.py --scene runs/patient_medium/scene.toml \
        --mesh runs/patient_medium/work/sweep/mesh.npz --out docs/solver_tolerance_patient.json \
        --settings 1e-8:0.001 1e-6:0.005 1e-4:0.01

Each setting's path is written to --work as it finishes (its fields, npz) and the JSON is
rewritten after each, so a stopped run resumes at the next setting. The first setting is the
reference. Run it alone: the times are the comparison.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import numpy as np

from fem_offline.fe.continuation import solve_path
from fem_offline.geometry.mesh import load
from fem_offline.fe.problem import build_problem
from fem_offline.scene import load_scene

REFERENCE = "1e-8:0.001"
DEFAULT_SETTINGS = [REFERENCE, "1e-6:0.005", "1e-5:0.005", "1e-4:0.005", "1e-5:0.01", "1e-4:0.01", "1e-4:0.02"]


def with_tolerances(scene, rtol: float, contact_tol_mm: float):
    """The scene with solver.rtol and guide.contact_tol_mm replaced (validated as a scene file would be)."""
    data = scene.model_dump()
    data["solver"]["rtol"] = rtol
    data["guide"]["contact_tol_mm"] = contact_tol_mm
    return type(scene).model_validate(data)


def run_path(scene, mesh, angle_deg: float, to_mm: float) -> tuple[np.ndarray, dict]:
    """(u (n_steps, n_nodes, 3), totals) of one path from rest."""
    problem = build_problem(scene, mesh)
    step = scene.sweep.displacement_step_mm
    ds = np.arange(step, to_mm + 1e-9, step)
    fields, total = [], dict(newton=0, cg=0, factorisations=0, contact_updates=0, halvings=0)
    t0 = time.perf_counter()
    for d, u, st in solve_path(problem, ds, angle_deg):
        fields.append(u)
        for key, value in zip(total, (st.iterations, st.cg_iterations, st.factorizations, st.contact_updates, st.halvings)):
            total[key] += value
        print(f"  {d:6.2f} mm: Newton {st.iterations:3d}, updates {st.contact_updates:2d}, {st.seconds:6.2f} s", flush=True)
    total["seconds"] = time.perf_counter() - t0
    total["steps"] = len(ds)
    return np.stack(fields), total


def distances(u: np.ndarray, ref: np.ndarray, sets: dict[str, np.ndarray]) -> dict:
    """Largest |u - ref| (mm) over the path's steps, per node set."""
    d = np.linalg.norm(u - ref, axis=-1)  # (n_steps, n_nodes)
    return {name: float(d[:, nodes].max()) for name, nodes in sets.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="fem_offline/scenes/default.toml")
    ap.add_argument("--mesh", required=True, help="mesh.npz of the scene (e.g. a sweep folder's)")
    ap.add_argument("--angle-deg", type=float, default=10.0)
    ap.add_argument("--to-mm", type=float, default=10.0)
    ap.add_argument("--settings", nargs="+", default=DEFAULT_SETTINGS,
                    help="rtol:contact_tol_mm pairs; the first is the reference")
    ap.add_argument("--out", type=Path, required=True, help="JSON written after each setting")
    ap.add_argument("--work", type=Path, default=Path("runs/solver_tolerance"))
    args = ap.parse_args()

    scene, mesh = load_scene(args.scene), load(args.mesh)
    sets = {"markers": mesh.node_sets["markers"], "prostate_surface": mesh.node_sets["prostate_surface"],
            "nodes": np.arange(len(mesh.nodes))}
    key = hashlib.sha256(Path(args.mesh).read_bytes()).hexdigest()[:12] + f"_b{args.angle_deg:g}_d{args.to_mm:g}"
    args.work.mkdir(parents=True, exist_ok=True)
    result = {"scene": str(args.scene), "mesh": str(args.mesh), "n_tets": int(len(mesh.tets)),
              "angle_deg": args.angle_deg, "to_mm": args.to_mm, "reference": args.settings[0], "settings": {}}
    if args.out.exists():
        old = json.loads(args.out.read_text())
        if old.get("mesh") == result["mesh"] and old.get("angle_deg") == args.angle_deg:
            result["settings"] = old["settings"]
    ref = None
    for setting in args.settings:
        rtol, tol = (float(x) for x in setting.split(":"))
        cached = args.work / f"{key}_{rtol:g}_{tol:g}.npz"
        if cached.exists() and setting in result["settings"]:
            u = np.load(cached)["u"]
        else:
            print(f"rtol {rtol:g}, contact_tol_mm {tol:g}: {len(mesh.tets)} tets, beta {args.angle_deg:g} deg", flush=True)
            u, total = run_path(with_tolerances(scene, rtol, tol), mesh, args.angle_deg, args.to_mm)
            np.savez(cached, u=u)
            result["settings"][setting] = {"rtol": rtol, "contact_tol_mm": tol, **total}
        if ref is None:
            ref = u
        row = result["settings"][setting]
        row["vs_reference_mm"] = distances(u, ref, sets)
        args.out.write_text(json.dumps(result, indent=1))
    base = result["settings"][args.settings[1]]["seconds"] if len(args.settings) > 1 else None
    print(f"\n{'rtol':>6} {'contact':>8} {'time s':>7} {'x':>5} {'Newton':>6} {'updates':>7} {'fact':>5}  "
          "max |u - u_ref| mm: markers / prostate surface / all nodes")
    for setting in args.settings:
        row = result["settings"][setting]
        if base:
            row["speedup_vs_first_nonreference"] = base / row["seconds"]
        v = row["vs_reference_mm"]
        print(f"{row['rtol']:6.0e} {row['contact_tol_mm']:8g} {row['seconds']:7.1f} {base / row['seconds'] if base else 1:5.2f} "
              f"{row['newton']:6d} {row['contact_updates']:7d} {row['factorisations']:5d}  "
              f"{v['markers']:.5f} / {v['prostate_surface']:.5f} / {v['nodes']:.5f}")
    args.out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
