"""Seed a grid-convergence study's level from a sweep of that level's scene and mesh (no solving again).

`python -m studies convergence-study` then takes its hard cases from the sweep's snapshots instead of
solving them again.

    python -m studies convergence-from-sweep --sweep runs/default_v7 --scale 0.769 --out runs/convergence_resolve
    MKL_NUM_THREADS=2 python -m studies convergence-study --guide contact --step-mm 0.5 \\
        --scales 1.3 1 0.769 --out runs/convergence_resolve --name convergence_resolve

The sweep must be of the study's scene at that scale (the same physics and mesh sizes; the
sweep's load steps, 0.25 mm, may differ from the study's): that is checked on every field but the
load step. Writes mesh_<scale>.npz (the sweep's mesh) and one path checkpoint per hard case at its
full displacement, marked with the study scene's hash, as convergence.solve_resumable writes them.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np

from contracts import sweep as folder
from studies.convergence import HARD_CASES, scaled_scene, study_scene


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies convergence-from-sweep", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sweep", type=Path, required=True)
    ap.add_argument("--scale", type=float, required=True, help="the study level the sweep is (sizes x scale)")
    ap.add_argument("--scene", type=Path, default=Path("fem_offline/scenes/grid_study_base.toml"))
    ap.add_argument("--step-mm", type=float, default=0.5, help="the study's load step (convergence_study.py --step-mm)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    manifest = folder.read_manifest(args.sweep)
    study = scaled_scene(study_scene(args.scene, contact=True, step_mm=args.step_mm), args.scale)
    # the sweep's scene with the study's name, grid and load step: the rest must be the study's
    swept = manifest.scene.model_copy(update={
        "name": study.name, "sweep": study.sweep,
        "solver": manifest.scene.solver.model_copy(update={"max_step_mm": study.solver.max_step_mm})})
    if swept != study:
        diff = sorted(k for k in type(study).model_fields if getattr(swept, k) != getattr(study, k))
        raise SystemExit(f"{args.sweep}: not the study's scene at scale {args.scale:g} (differs in {diff})")
    args.out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(args.sweep / folder.MESH_FILE, args.out / f"mesh_{args.scale:g}.npz")
    grid = manifest.grid
    for d, beta in HARD_CASES:
        i, j = list(grid.angles_deg).index(beta), list(grid.displacements_mm).index(d)
        with np.load(args.sweep / folder.snapshot_file(i, j)) as z:
            u = z["displacement"].ravel()
        seconds = 0.0
        for k in range(j + 1):
            with np.load(args.sweep / folder.snapshot_file(i, k)) as z:
                seconds += float(z["seconds"])
        path = args.out / f"path_{args.scale:g}_{d:g}_{beta:g}.npz"
        np.savez(path, u=u, d_mm=d, seconds=seconds, history_d=np.zeros(0), history_u=np.zeros((0, u.size)),
                 scene_sha256=study.sha256())
        print(f"{path}: {d:g} mm, {beta:g} deg from {folder.snapshot_file(i, j)} ({seconds:.0f} s of the sweep's path)")
    (args.out / "seeded.json").write_text(json.dumps({"sweep": str(args.sweep), "scale": args.scale}) + "\n")
