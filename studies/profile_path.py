"""One displacement path of a scene on a given mesh, step by step: Newton and CG iterations,
factorisations, multiplier updates and time per load step, and their totals.

    python scripts/profile_path.py --mesh runs/default_contact/mesh.npz --angle-deg 10 --to-mm 10
    python scripts/profile_path.py --scale 0.5917 --volumetric taylor_hood --mesh runs/p32/mesh.npz

--scale S multiplies every mesh size of the scene (a level of the convergence study, which scales
fem_offline/scenes/default.toml); the scene is meshed into --mesh when that file does not exist yet.

What the solver's iteration counts are worth is read here, not from a sweep's wall time (several
paths share the cores there). Set MKL_NUM_THREADS to compare like with like.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from fem_offline.fe.continuation import solve_path
from studies.convergence import scaled_scene, study_scene
from fem_offline.geometry.meshing import kept_mesh
from fem_offline.geometry.mesh import load
from fem_offline.fe.problem import build_problem
from fem_offline.scene import VOLUMETRIC


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="fem_offline/scenes/default.toml")
    ap.add_argument("--mesh", type=Path, required=True,
                    help="mesh.npz of the scene (e.g. a sweep folder's); meshed from the scene if it does not exist")
    ap.add_argument("--scale", type=float, help="every mesh size of the scene x SCALE (a convergence study level)")
    ap.add_argument("--volumetric", choices=VOLUMETRIC,
                    help="the scene's solver.volumetric instead of its own")
    ap.add_argument("--angle-deg", type=float, default=10.0)
    ap.add_argument("--to-mm", type=float, default=10.0)
    ap.add_argument("--double-factors", action="store_true",
                    help="precondition with float64 PARDISO factors instead of float32 (newton.SINGLE_FACTORS)")
    args = ap.parse_args()
    if args.double_factors:
        import fem_offline.fe.newton as newton

        newton.SINGLE_FACTORS = False
    scene = study_scene(args.scene, volumetric=args.volumetric)
    if args.scale is not None:
        if not args.scale > 0:
            ap.error(f"--scale: {args.scale:g} must be > 0")
        scene = scaled_scene(scene, args.scale)
    problem = build_problem(scene, kept_mesh(scene, args.mesh) if args.mesh.suffix == ".npz" else load(args.mesh))
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
