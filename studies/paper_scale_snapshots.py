"""Snapshots on the paper-scale mesh, interpolated from the default sweep, to time a paper-scale decoder.

    python -m fem_offline mesh --scene fem_offline/scenes/paper_scale.toml --out runs/paper/mesh.npz
    python -m studies paper-scale-snapshots --sweep runs/default --mesh runs/paper/mesh.npz \
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
from pathlib import Path

import numpy as np

from contracts import sweep as folder
from contracts.files import sha256
from contracts.interpolate import PointLocator, interpolation_matrix
from contracts.mesh import write_mesh
from fem_offline.geometry.mesh import load


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies paper-scale-snapshots", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sweep", type=Path, required=True)
    ap.add_argument("--mesh", type=Path, required=True,
                    help="the fine mesh (.npz, or any format fem_offline mesh writes)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--angle-stride", type=int, default=2, help="keep every n-th angle (default 2: 11 x 40 = 440)")
    args = ap.parse_args(argv)

    source = folder.read_sweep(args.sweep)
    coarse, fine = source.mesh, load(args.mesh)
    outside = int((PointLocator(coarse.nodes, coarse.tets).locate(fine.nodes)[0] < 0).sum())
    print(f"{len(fine.nodes)} fine nodes, {outside} outside the coarse mesh (clipped to the nearest tet)")
    W = interpolation_matrix(coarse.nodes, coarse.tets, fine.nodes, nearest=True)  # (n_fine, n_coarse)
    m = source.manifest
    angles = m.grid.angles_deg[:: args.angle_stride]
    write_mesh(args.out / folder.MESH_FILE, fine)
    rows = []
    for i, angle in enumerate(angles):
        for j, d in enumerate(m.grid.displacements_mm):
            k = np.flatnonzero((source.inputs[:, 0] == d) & (source.inputs[:, 1] == angle))[0]
            src = m.snapshots[k]
            name = folder.snapshot_file(i, j)
            record = folder.CaseRecord(newton_iterations=src.newton_iterations, residual=src.residual,
                                       min_det_f=src.min_det_f, seconds=src.seconds)
            folder.write_case(args.out / name, W @ source.displacement[k], displacement_mm=d, angle_deg=angle,
                              record=record)
            rows.append(folder.snapshot_record(args.out, name))
    grid = folder.Grid(displacements_mm=m.grid.displacements_mm, angles_deg=angles)
    folder.write_manifest(args.out, m.model_copy(update={
        "scene_name": "paper_scale_interpolated", "mesh_sha256": sha256(args.out / folder.MESH_FILE),
        "n_nodes": len(fine.nodes), "n_tets": len(fine.tets), "grid": grid, "envelope": grid.envelope,
        "n_expected": len(rows), "n_done": len(rows), "n_mirrored": 0, "errors": [], "snapshots": rows}))
    print(f"{args.out}: {len(rows)} snapshots on {len(fine.nodes)} nodes, {len(fine.tets)} tets")
    return 0
