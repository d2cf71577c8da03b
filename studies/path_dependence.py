"""Does an equilibrium depend on the path that reached it? One case (d, beta) solved from rest and
from another angle's equilibrium (as `fem_offline cases --sweep` starts an off-grid case), at the
default tolerances and at tight ones (solver.rtol, guide.contact_tol_mm).

    MKL_NUM_THREADS=1 python scripts/path_dependence.py --mesh runs/p/mesh.npz --case 6.5 9 --start-angle 10

The physics is conservative, so the two starts must reach one equilibrium; what the solver's
tolerances leave open shows as a difference between them, which must shrink with the tolerances.
The off-grid error of a model whose cases started from the sweep includes that difference.
Prints max |u_rest - u_start| at the markers, the prostate surface and every node, per tolerance.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from fem_offline.cases import solve_from
from fem_offline.fe.continuation import solve_path
from fem_offline.geometry.mesh import load
from fem_offline.fe.problem import build_problem
from fem_offline.scene import load_scene

from solver_tolerance import with_tolerances  # scripts/ is on sys.path when run as a script


def path_to(problem, d_mm: float, angle_deg: float) -> np.ndarray:
    """The equilibrium at (d, beta) from rest, in the scene's displacement steps: u (n_dofs,)."""
    step = problem.scene.sweep.displacement_step_mm
    ds = np.append(np.arange(step, d_mm - 1e-9, step), d_mm)
    *_, (_, u, _) = solve_path(problem, ds, angle_deg)
    return u.ravel()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="fem_offline/scenes/default.toml")
    ap.add_argument("--mesh", required=True)
    ap.add_argument("--case", type=float, nargs=2, default=[6.5, 9.0], metavar=("D_MM", "BETA_DEG"))
    ap.add_argument("--start-angle", type=float, default=10.0, help="the other path's angle the second start comes from")
    ap.add_argument("--tolerances", nargs="+", default=["1e-6:0.005", "1e-8:0.0005"], help="rtol:contact_tol_mm")
    ap.add_argument("--out", type=Path, default=Path("docs/path_dependence.json"))
    args = ap.parse_args()
    scene, mesh = load_scene(args.scene), load(args.mesh)
    d, beta = args.case
    sets = {"markers": mesh.node_sets["markers"], "prostate_surface": mesh.node_sets["prostate_surface"],
            "nodes": np.arange(len(mesh.nodes))}
    t0 = time.perf_counter()
    start = path_to(build_problem(scene, mesh), d, args.start_angle)
    print(f"start: {d:g} mm at {args.start_angle:g} deg from rest, {time.perf_counter() - t0:.0f} s", flush=True)
    rows = {}
    for setting in args.tolerances:
        rtol, tol = (float(x) for x in setting.split(":"))
        problem = build_problem(with_tolerances(scene, rtol, tol), mesh)
        t0 = time.perf_counter()
        rest = path_to(problem, d, beta)
        t_rest, t0 = time.perf_counter() - t0, time.perf_counter()
        moved, stats = solve_from(problem, start, d, beta)
        t_start = time.perf_counter() - t0
        diff = np.linalg.norm(rest.reshape(-1, 3) - moved.reshape(-1, 3), axis=1)
        rows[setting] = {"rtol": rtol, "contact_tol_mm": tol, "seconds_from_rest": t_rest, "seconds_from_start": t_start,
                         "max_diff_mm": {k: float(diff[v].max()) for k, v in sets.items()}}
        print(f"rtol {rtol:g}, contact_tol_mm {tol:g}: from rest {t_rest:.0f} s, from {args.start_angle:g} deg "
              f"{t_start:.0f} s; max |u_rest - u_start| markers {diff[sets['markers']].max():.5f}, prostate surface "
              f"{diff[sets['prostate_surface']].max():.5f}, all nodes {diff.max():.5f} mm", flush=True)
    args.out.write_text(json.dumps({"scene": args.scene, "mesh": args.mesh, "n_tets": int(len(mesh.tets)),
                                    "case": {"d_mm": d, "angle_deg": beta}, "start_angle_deg": args.start_angle,
                                    "rows": rows}, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
