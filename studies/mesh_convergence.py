"""How far the default mesh's answer is from a mesh with every size halved, in mm at the prostate.

    python -m studies mesh-convergence [--scene fem_offline/scenes/grid_study_base.toml] [--displacement-mm 10] [--angle-deg 10]

Solves the same case on both meshes (linear and nonlinear) and evaluates the fine P2 solution at
the coarse mesh's prostate-surface nodes (interpolation inside the containing fine tet).
PARDISO's threads come from the caller's MKL_NUM_THREADS (e.g. 2 to use both cores of a small machine).
"""  # noqa: E501 -- argparse prints this docstring as it is (--help)

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from contracts.interpolate import interpolation_matrix
from fem_offline.geometry.meshing import mesh_for_scene
from fem_offline.fe.problem import build_problem
from fem_offline.scene import load_scene
from fem_offline.fe.solve import solve_case


def _solve(scene, mesh, nonlinear: bool, d: float, beta: float, step_mm: float):
    s = scene.model_copy(update={"effects": scene.effects.model_copy(update={"geometric_nonlinearity": nonlinear})})
    t0 = time.perf_counter()
    u, _ = solve_case(build_problem(s, mesh), d, beta, step_mm=step_mm)
    return u, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies mesh-convergence", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=Path("fem_offline/scenes/grid_study_base.toml"))
    ap.add_argument("--displacement-mm", type=float, default=10.0)
    ap.add_argument("--angle-deg", type=float, default=10.0)
    ap.add_argument("--step-mm", type=float, default=0.5,
                    help="load step (hyperelastic: the end state does not depend on it)")
    ap.add_argument("--linear-only", action="store_true")
    args = ap.parse_args(argv)
    coarse_scene = load_scene(args.scene)
    sizes = coarse_scene.mesh
    fine_scene = coarse_scene.model_copy(update={"mesh": sizes.model_copy(update={
        "max_mm": sizes.max_mm / 2, "prostate_mm": sizes.prostate_mm / 2, "guide_mm": sizes.guide_mm / 2})})
    coarse, fine = mesh_for_scene(coarse_scene), mesh_for_scene(fine_scene)
    print(f"coarse {len(coarse.tets)} tets, fine {len(fine.tets)} tets")
    surface = coarse.nodes[coarse.node_sets["prostate_surface"]]
    probe = interpolation_matrix(fine.nodes, fine.tets, surface)  # P2 transfer
    for nonlinear in ([False] if args.linear_only else [False, True]):
        case = (nonlinear, args.displacement_mm, args.angle_deg, args.step_mm)
        uc, tc = _solve(coarse_scene, coarse, *case)
        uf, tf = _solve(fine_scene, fine, *case)
        at = probe @ uf
        err = np.linalg.norm(uc[coarse.node_sets["prostate_surface"]] - at, axis=1)
        peak = np.linalg.norm(at, axis=1).max()
        print(f"{'nonlinear' if nonlinear else 'linear'} {args.displacement_mm} mm, beta {args.angle_deg} deg: "
              f"prostate surface |u_coarse - u_fine| max {err.max():.3f} mm, mean {err.mean():.3f} mm (peak prostate "
              f"motion {peak:.2f} mm); solve {tc:.0f} s coarse, {tf:.0f} s fine")
