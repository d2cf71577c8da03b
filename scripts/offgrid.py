"""Solve random off-grid (displacement, angle) cases with `python -m fem_offline solve`, for held-out evaluation.

    python scripts/offgrid.py --scene fem_offline/scenes/default.toml --mesh runs/default/mesh.vtu \
        --out runs/default/offgrid --n 24 --seed 0

The cases are drawn uniformly inside the scene's sweep envelope from a fixed seed, so the same
command gives the same cases. Finished cases are skipped, so an interrupted run resumes.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from fem_offline.scene import load_scene  # noqa: E402


def cases(scene, n: int, seed: int) -> list[tuple[float, float]]:
    sweep = scene.sweep
    rng = np.random.default_rng(seed)
    d = rng.uniform(sweep.displacement_step_mm, sweep.displacement_max_mm, n)
    a = rng.uniform(sweep.angle_min_deg, sweep.angle_max_deg, n)
    return [(round(float(x), 3), round(float(y), 3)) for x, y in zip(d, a)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True, type=Path)
    ap.add_argument("--mesh", type=Path, help="the sweep's mesh.vtu (so the cases share its nodes)")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()

    scene = load_scene(args.scene)
    args.out.mkdir(parents=True, exist_ok=True)
    todo = []
    for i, (d, a) in enumerate(cases(scene, args.n, args.seed)):
        out = args.out / f"offgrid_{i:03d}.npz"
        if out.exists():
            continue
        cmd = [sys.executable, "-m", "fem_offline", "solve", "--scene", str(args.scene),
               "--displacement-mm", str(d), "--angle-deg", str(a), "--out", str(out)]
        if args.mesh:
            cmd += ["--mesh", str(args.mesh)]
        todo.append(cmd)
    print(f"{args.n - len(todo)} of {args.n} cases already solved; solving {len(todo)}", flush=True)

    def run(cmd):
        proc = subprocess.run(cmd, capture_output=True, text=True, env={**__import__("os").environ, "MKL_NUM_THREADS": "1"})
        print((proc.stdout or proc.stderr).strip(), flush=True)
        return proc.returncode

    with ThreadPoolExecutor(args.workers) as pool:
        codes = list(pool.map(run, todo))
    return max(codes, default=0)


if __name__ == "__main__":
    sys.exit(main())
