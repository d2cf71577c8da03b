"""One displacement path of a scene on a given mesh, step by step: Newton and CG iterations,
factorisations, multiplier updates and time per load step, and their totals.

    python scripts/profile_path.py --mesh runs/default_contact/mesh.npz --angle-deg 10 --to-mm 10

What the solver's iteration counts are worth is read here, not from a sweep's wall time (several
paths share the cores there). Set MKL_NUM_THREADS to compare like with like.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fem_offline.continuation import solve_path
from fem_offline.mesh import load
from fem_offline.problem import build_problem
from fem_offline.scene import load_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="fem_offline/scenes/default.toml")
    ap.add_argument("--mesh", required=True, help="mesh.npz of the scene (e.g. a sweep folder's)")
    ap.add_argument("--angle-deg", type=float, default=10.0)
    ap.add_argument("--to-mm", type=float, default=10.0)
    ap.add_argument("--double-factors", action="store_true",
                    help="precondition with float64 PARDISO factors instead of float32 (newton.SINGLE_FACTORS)")
    args = ap.parse_args()
    if args.double_factors:
        import fem_offline.newton as newton

        newton.SINGLE_FACTORS = False
    scene = load_scene(args.scene)
    problem = build_problem(scene, load(args.mesh))
    step = scene.sweep.displacement_step_mm
    ds = np.arange(step, args.to_mm + 1e-9, step)
    print(f"{args.mesh}: {len(problem.mesh.tets)} tets, {problem.n_dofs} DOFs; beta {args.angle_deg:g} deg, "
          f"{len(ds)} steps of {step:g} mm")
    total = dict(newton=0, cg=0, factorisations=0, updates=0, halvings=0)
    t0 = time.perf_counter()
    for d, _, st in solve_path(problem, ds, args.angle_deg):
        print(f"  {d:6.2f} mm: Newton {st.iterations:3d}, CG {st.cg_iterations:4d}, factorisations {st.factorizations:2d}, "
              f"updates {st.contact_updates:2d}, {st.seconds:6.2f} s, min det F {st.min_det_f:.3f}", flush=True)
        for key, value in zip(total, (st.iterations, st.cg_iterations, st.factorizations, st.contact_updates, st.halvings)):
            total[key] += value
    print("total: " + ", ".join(f"{k} {v}" for k, v in total.items()) + f"; {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
