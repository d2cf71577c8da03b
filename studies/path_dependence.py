"""Does an equilibrium depend on the path that reached it? One case from rest and from another angle's.

One case (d, beta) solved from rest and from another angle's equilibrium (as `fem_offline cases --sweep` starts an off-grid case), at the
default tolerances and at tight ones (solver.rtol, guide.contact_tol_mm).

    MKL_NUM_THREADS=1 python -m studies path-dependence --mesh runs/p/mesh.npz --case 6.5 9 --start-angle 10 [--publish]

The physics is conservative, so the two starts must reach one equilibrium; what the solver's
tolerances leave open shows as a difference between them, which must shrink with the tolerances.
The off-grid error of a model whose cases started from the sweep includes that difference.
Prints max |u_rest - u_start| at the markers, the prostate surface and every node, per tolerance.
"""  # noqa: E501 -- argparse prints this docstring as it is (--help)

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from fem_offline.cases import solve_from
from fem_offline.fe.continuation import solve_path
from fem_offline.geometry.mesh import load
from fem_offline.fe.problem import build_problem
from fem_offline.scene import load_scene
from contracts.cli import number
from studies import results
from studies.options import add_scene_flag, parser, tolerance_arg, with_tolerances


def path_to(problem, d_mm: float, angle_deg: float) -> np.ndarray:
    """The equilibrium at (d, beta) from rest, in the scene's displacement steps: u (n_dofs,)."""
    step = problem.scene.sweep.displacement_step_mm
    ds = np.append(np.arange(step, d_mm - 1e-9, step), d_mm)
    *_, (_, u, _) = solve_path(problem, ds, angle_deg)
    return u.ravel()


def main(argv: list[str] | None = None) -> int:
    ap = parser("python -m studies path-dependence", __doc__)
    add_scene_flag(ap)
    ap.add_argument("--mesh", type=Path, required=True, help="mesh.npz of the scene")
    ap.add_argument("--case", type=number("--case"), nargs=2, default=[6.5, 9.0], metavar=("D_MM", "BETA_DEG"))
    ap.add_argument("--start-angle", type=number("--start-angle"), default=10.0,
                    help="the other path's angle the second start comes from")
    ap.add_argument("--tolerances", type=tolerance_arg, nargs="+", default=[(1e-6, 0.005), (1e-8, 0.0005)],
                    metavar="RTOL:CONTACT_TOL_MM")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    scene, mesh = load_scene(args.scene), load(args.mesh)
    d, beta = args.case
    sets = {"markers": mesh.node_sets["markers"], "prostate_surface": mesh.node_sets["prostate_surface"],
            "nodes": np.arange(len(mesh.nodes))}
    t0 = time.perf_counter()
    start = path_to(build_problem(scene, mesh), d, args.start_angle)
    print(f"start: {d:g} mm at {args.start_angle:g} deg from rest, {time.perf_counter() - t0:.0f} s", flush=True)
    rows = {}
    for rtol, tol in tqdm(args.tolerances, desc="tolerances", unit="setting"):
        setting = f"{rtol:g}:{tol:g}"
        problem = build_problem(with_tolerances(scene, rtol, tol), mesh)
        t0 = time.perf_counter()
        rest = path_to(problem, d, beta)
        t_rest, t0 = time.perf_counter() - t0, time.perf_counter()
        moved, stats = solve_from(problem, start, d, beta)
        t_start = time.perf_counter() - t0
        diff = np.linalg.norm(rest.reshape(-1, 3) - moved.reshape(-1, 3), axis=1)
        rows[setting] = {"rtol": rtol, "contact_tol_mm": tol, "seconds_from_rest": t_rest,
                         "seconds_from_start": t_start,
                         "max_diff_mm": {k: float(diff[v].max()) for k, v in sets.items()}}
        print(f"rtol {rtol:g}, contact_tol_mm {tol:g}: from rest {t_rest:.0f} s, from {args.start_angle:g} deg "
              f"{t_start:.0f} s; max |u_rest - u_start| markers {diff[sets['markers']].max():.5f}, prostate surface "
              f"{diff[sets['prostate_surface']].max():.5f}, all nodes {diff.max():.5f} mm", flush=True)
    path = results.write("path_dependence", {"scene": str(args.scene), "mesh": str(args.mesh),
                                             "n_tets": int(len(mesh.tets)), "case": {"d_mm": d, "angle_deg": beta},
                                             "start_angle_deg": args.start_angle, "rows": rows}, publish=args.publish)
    print(f"wrote {path}")
    return 0
