"""How much the contact model's answer changes from one mesh level to the next, at the probe points.

    python -m studies refinement-changes [--scales 1.3 1 0.77]

Reads the grid-convergence checkpoints of the tip in contact (runs/convergence_contact, written by
`python -m studies convergence-study --guide contact --step-mm 0.5 --scales ...`; this solves nothing)
and prints, per hard case and pair of consecutive levels, the largest change of the displacement
vector at the markers, the prostate surface (near the tip and the rest) and the interior points.
A level whose size ratio to the next is not the study's (0.77: 1 / 0.77 = 1.299 < 1.3) cannot enter
the GCI analysis; this shows what refinement does to it.
"""

from __future__ import annotations

import argparse

import numpy as np

from contracts.mesh import read_mesh
from studies.convergence import HARD_CASES, NEAR_TIP_MM, at_points, probe_points, study_scene


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies refinement-changes", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scales", type=float, nargs="+", default=[1.3, 1.0, 0.77], help="levels, coarsest first")
    ap.add_argument("--out", default="runs/convergence_contact")
    args = ap.parse_args(argv)
    scene = study_scene("fem_offline/scenes/grid_study_base.toml", contact=True, step_mm=0.5)
    probes = probe_points(read_mesh(f"{args.out}/mesh_1.npz"), scene)
    probes.pop("nodes")
    near = np.linalg.norm(probes["prostate_surface"] - np.asarray(scene.guide.tip_mm), axis=1) < NEAR_TIP_MM
    meshes = {s: read_mesh(f"{args.out}/mesh_{s:g}.npz") for s in args.scales}
    for d, beta in HARD_CASES:
        u = {}
        for s, mesh in meshes.items():
            with np.load(f"{args.out}/path_{s:g}_{d:g}_{beta:g}.npz") as z:
                field = z["u"].reshape(-1, 3)
            u[s] = {k: at_points(mesh, field, p) for k, p in probes.items()}
        for a, b in zip(args.scales, args.scales[1:]):
            ch = {k: np.linalg.norm(u[b][k] - u[a][k], axis=1) for k in probes}
            print(f"{d:g} mm {beta:g} deg, {len(meshes[a].tets)} -> {len(meshes[b].tets)} tets: markers "
                  f"{ch['markers'].max():.3f}, surface near tip {ch['prostate_surface'][near].max():.3f}, rest "
                  f"{ch['prostate_surface'][~near].max():.3f}, interior {ch['interior'].max():.3f} mm")
    return 0
