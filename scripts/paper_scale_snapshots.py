"""Snapshots on the paper-scale mesh, interpolated from the default sweep, to time a paper-scale decoder.

    python -m fem_offline mesh --scene fem_offline/scenes/paper_scale.toml --out runs/paper/mesh.vtu
    python scripts/paper_scale_snapshots.py --sweep runs/default --mesh runs/paper/mesh.vtu \
        --out runs/paper/sweep_interp --angle-stride 2
    python -m training fit --snapshots runs/paper/sweep_interp --out runs/paper/model --rank 32 \
        --test-case 7.75/-4 --test-case 2.5/2

Each node of the fine mesh (225,938 tets, 312,089 nodes) gets the default sweep's displacement
interpolated with the quadratic shape functions of the coarse tet that contains it. The fields
are FE-quality only to the coarse mesh's accuracy: this folder exists to time decoding
(latency depends on node count and rank, not on the values), not to measure accuracy.
Fine nodes just outside the coarse mesh (its curved surfaces are chords of the fine ones)
take the value at their projection onto the nearest coarse tet (`interpolation_matrix(..., nearest=True)`).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from fem_offline.io import atomic_savez  # noqa: E402
from fem_offline.mesh import load  # noqa: E402
from contracts.interpolate import PointLocator, interpolation_matrix  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sweep", type=Path, required=True)
    ap.add_argument("--mesh", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--angle-stride", type=int, default=2, help="keep every n-th angle (default 2: 11 x 40 = 440)")
    args = ap.parse_args()

    manifest = json.loads((args.sweep / "manifest.json").read_text())
    coarse, fine = load(args.sweep / manifest["mesh"]), load(args.mesh)
    outside = int((PointLocator(coarse.nodes, coarse.tets).locate(fine.nodes)[0] < 0).sum())
    print(f"{len(fine.nodes)} fine nodes, {outside} outside the coarse mesh (clipped to the nearest tet)")
    W = interpolation_matrix(coarse.nodes, coarse.tets, fine.nodes, nearest=True)  # (n_fine, n_coarse)
    keep_angles = manifest["angles_deg"][:: args.angle_stride]
    (args.out / "snapshots").mkdir(parents=True, exist_ok=True)
    for suffix in (".vtu", ".json"):
        shutil.copy(args.mesh.with_suffix(suffix), args.out / f"mesh{suffix}")
    files = sorted((args.sweep / "snapshots").glob("*.npz"))
    n = 0
    for f in files:
        with np.load(f) as z:
            if float(z["angle_deg"]) not in keep_angles:
                continue
            atomic_savez(args.out / "snapshots" / f.name, displacement=W @ z["displacement"],
                         displacement_mm=z["displacement_mm"], angle_deg=z["angle_deg"])
            n += 1
    out_manifest = {**manifest, "scene_name": "paper_scale_interpolated", "mesh": "mesh.vtu", "n_expected": n,
                    "n_done": n, "n_nodes": len(fine.nodes), "n_tets": len(fine.tets), "angles_deg": keep_angles,
                    "interpolated_from": str(args.sweep)}
    (args.out / "manifest.json").write_text(json.dumps(out_manifest, indent=2))
    print(f"{args.out}: {n} snapshots on {len(fine.nodes)} nodes, {len(fine.tets)} tets")
    return 0


if __name__ == "__main__":
    sys.exit(main())
