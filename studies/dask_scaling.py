"""How the sweep scales on a Dask cluster: 1 and 2 single-threaded workers, and a projection to N machines.

How the sweep scales on a Dask cluster: the same paths on a LocalCluster of 1 and 2 single-threaded
workers, and a projection to N machines.

    python -m studies dask-scaling [--scene fem_offline/scenes/grid_study_base.toml] [--angles 4] [--to-mm 2]

Runs `run_sweep(..., scheduler=...)`, the code path `fem_offline sweep --scheduler tcp://...` takes,
on a reduced grid (the first `--angles` angles from 0 deg up, displacements up to `--to-mm`) into
fresh folders, and prints the wall time and speed-up per worker count. The projection: a sweep is
independent paths (one per solved angle; 11 for the default 21 x 40 grid with the mirror), each a
sequence of load steps that cannot be split, so with W workers it takes about ceil(paths / W) times
one path, measured here per worker count. Workers beyond the number of paths add nothing.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

from fem_offline.scene import load_scene
from fem_offline.sweep import grid, run_sweep


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies dask-scaling", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="fem_offline/scenes/grid_study_base.toml")
    ap.add_argument("--angles", type=int, default=4, help="paths in the reduced grid (angles 0, 1, ... deg)")
    ap.add_argument("--to-mm", type=float, default=2.0)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = ap.parse_args(argv)
    from distributed import Client, LocalCluster

    full = load_scene(args.scene)
    step = full.sweep.angle_step_deg
    sweep = full.sweep.model_copy(update={"angle_min_deg": 0.0, "angle_max_deg": step * (args.angles - 1),
                                          "displacement_max_mm": args.to_mm})
    scene = full.model_copy(update={"sweep": sweep})
    n_paths, n_steps = len(grid(scene)), len(scene.sweep.displacements_mm)
    print(f"{full.name}: {n_paths} paths x {n_steps} steps of {scene.sweep.displacement_step_mm:g} mm "
          "on a LocalCluster")
    wall = {}
    for w in args.workers:
        with tempfile.TemporaryDirectory() as tmp, LocalCluster(n_workers=w, threads_per_worker=1, processes=True,
                                                                dashboard_address=None) as cluster, Client(cluster):
            t0 = time.perf_counter()
            manifest = run_sweep(scene, Path(tmp) / "sweep", scheduler=cluster.scheduler_address)
            wall[w] = time.perf_counter() - t0
            per_path = sum(r.seconds for r in manifest.snapshots) / n_paths
        print(f"  {w} worker(s): {wall[w]:.1f} s wall, {manifest.n_done} snapshots, one path {per_path:.1f} s "
              f"(solver time), speed-up {wall[args.workers[0]] / wall[w]:.2f}x")
    full_paths = (len([p for p in grid(full) if p[0].angle_deg >= 0]) if full.sweep.angle_min_deg < 0
                  else len(grid(full)))
    print(f"projection for the full grid ({full_paths} solved paths): "
          f"sweep time = ceil({full_paths} / workers) x one path:")
    for cores in (2, 4, 8, 11, 16):
        print(f"  {cores:2d} single-threaded workers (e.g. {math.ceil(cores / 2)} machines like this one): "
              f"{math.ceil(full_paths / cores)} path(s) in a row")
