"""One displacement path of a scene on a given mesh, step by step, with the solver's work per load step.

Newton and CG iterations, factorisations, multiplier updates and time per load step, and their totals.

    python -m studies profile-path --mesh runs/default_contact/mesh.npz --angle-deg 10 --to-mm 10
    python -m studies profile-path --scale 0.5917 --volumetric taylor_hood --mesh runs/p32/mesh.npz

--scale S multiplies every mesh size of the scene (a level of the convergence study, which scales
fem_offline/scenes/grid_study_base.toml); the scene is meshed into --mesh when that file does not exist yet.

What the solver's iteration counts are worth is read here, not from a sweep's wall time (several
paths share the cores there). Set MKL_NUM_THREADS to compare like with like.
"""

from __future__ import annotations

from pathlib import Path

from contracts.cli import number
from fem_offline.geometry.meshing import kept_mesh
from fem_offline.geometry.mesh import load
from fem_offline.fe.problem import build_problem
from fem_offline.scene import VOLUMETRIC
from studies.convergence import scaled_scene, study_scene
from studies.options import add_scene_flag, parser
from studies.stepping import stepped_path


def main(argv: list[str] | None = None) -> int:
    ap = parser("python -m studies profile-path", __doc__)
    add_scene_flag(ap)
    ap.add_argument("--mesh", type=Path, required=True,
                    help="mesh.npz of the scene (e.g. a sweep folder's); meshed from the scene if it does not exist")
    ap.add_argument("--scale", type=number("--scale", minimum=1e-3),
                    help="every mesh size of the scene x SCALE (a convergence study level)")
    ap.add_argument("--volumetric", choices=VOLUMETRIC,
                    help="the scene's solver.volumetric instead of its own")
    ap.add_argument("--angle-deg", type=number("--angle-deg"), default=10.0)
    ap.add_argument("--to-mm", type=number("--to-mm", minimum=0.0), default=10.0)
    ap.add_argument("--double-factors", action="store_true",
                    help="precondition with float64 PARDISO factors instead of float32 (newton.SINGLE_FACTORS)")
    args = ap.parse_args(argv)
    if args.double_factors:
        import fem_offline.fe.newton as newton

        newton.SINGLE_FACTORS = False
    scene = study_scene(args.scene, volumetric=args.volumetric)
    if args.scale is not None:
        scene = scaled_scene(scene, args.scale)
    problem = build_problem(scene, kept_mesh(scene, args.mesh) if args.mesh.suffix == ".npz" else load(args.mesh))
    step = scene.sweep.displacement_step_mm
    print(f"{args.mesh}: {len(problem.mesh.tets)} tets, {problem.n_dofs} DOFs; beta {args.angle_deg:g} deg, "
          f"steps of {step:g} mm to {args.to_mm:g} mm")
    _, total = stepped_path(problem, args.angle_deg, args.to_mm)
    print("total: " + ", ".join(f"{k} {v}" for k, v in total.items() if k != "seconds") + f"; {total['seconds']:.1f} s")
    return 0
