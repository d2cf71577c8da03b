"""Meshes graded where the error is, judged against the converged estimate of a grid-convergence study.

    python -m studies graded-mesh --sizes 15.6:4:2 15.6:3.08:1.54 [--study runs/convergence_contact_taylor_hood] \
        [--scales 1.3 1 0.769 0.5917] [--out runs/graded] [--publish]

Each --sizes MAX:PROSTATE:GUIDE[:SURFACE] sets the scene's [mesh] sizes (mm): far from everything, at the
prostate (growing to MAX over 25 mm), around the guide tip, and on the prostate's surface near the tip
(mesh.surface_near_tip_mm; left out: none). Unlike the study's levels, which scale all three
together, these refine only near the prostate or the tip. Each mesh solves the hard cases (resumably, every
load step checkpointed under --out) with the study's physics (grid_study_base.toml, the tip in contact, the
Taylor-Hood element, 0.5 mm load steps), and is judged as the study judges a level coarser than its
three: per point, |u_mesh - u_fine| + GCI_fine (studies.convergence.converged_estimate), at the
study's probe points (its 8 markers, 3 interior points and the 886 prostate-surface nodes of its scale-1
mesh, so that the surface figure includes interpolation between the graded mesh's own nodes; and all its
nodes, as the study's "every node") and at the graded mesh's own prostate-surface nodes and every node.
Each bound is the mesh's gap to the fine level plus the fine level's own band, so no mesh gets under the
band: the JSON gives the band's maximum per zone and, at the surface point away from the tip that bounds
the rest, the two parts. Prints one line per mesh and case. The result graded_mesh (runs/results/, or
docs/results/ with --publish) merges the meshes of every run into that folder's file.
"""

from __future__ import annotations

import argparse
import logging
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from contracts.mesh import read_mesh
from studies.convergence import (HARD_CASES, NEAR_TIP_MM, at_points, case_levels, converged_estimate, probe_points,
                                     solve_resumable, study_scene)
from fem_offline.geometry.meshing import kept_mesh
from fem_offline.fe.problem import build_problem
from studies import results
from studies.options import add_cases_flag, add_scene_flag, add_study_flags, case_text, parser as study_parser
from tqdm import tqdm


def sizes_arg(text: str) -> tuple[float, ...]:
    try:
        sizes = tuple(float(x) for x in text.split(":"))
    except ValueError:
        sizes = ()
    if len(sizes) not in (3, 4):
        raise argparse.ArgumentTypeError(f"--sizes: {text!r} is not MAX:PROSTATE:GUIDE[:SURFACE] in mm (e.g. 15.6:4:2)")
    if min(sizes) <= 0.05 or max(sizes[1:]) > sizes[0]:
        raise argparse.ArgumentTypeError(f"--sizes: {text!r} needs 0.05 < PROSTATE, GUIDE, SURFACE <= MAX")
    return sizes


def tag(sizes) -> str:
    """The sizes, exact (15.600000000000001 = 12 x 1.3 meshes differently from 15.6), as a folder name."""
    return "_".join(repr(float(s)).removesuffix(".0") for s in sizes)


def command(sizes, args, cases) -> str:
    """The command that judges one mesh as this run did (the file merges meshes of several runs)."""
    return shlex.join(["python", "-m", "studies", "graded-mesh", "--sizes", tag(sizes).replace("_", ":"),
                       "--scene", str(args.scene), "--study", str(args.study), "--scales",
                       *(f"{s:g}" for s in args.scales),
                       "--cases", *map(case_text, cases)] + (["--publish"] if args.publish else []))


def judge(scene, sizes, study: Path, scales: list[float], cases, out: Path) -> dict:
    """Mesh with `sizes`, solve `cases`, and bound each answer's distance to the study's converged estimate."""
    mx, prostate, guide, shell = (*sizes, None) if len(sizes) == 3 else sizes
    scene = scene.model_copy(update={"mesh": scene.mesh.model_copy(
        update={"max_mm": mx, "prostate_mm": prostate, "guide_mm": guide, "surface_near_tip_mm": shell})})
    folder = out / tag(sizes)
    mesh = kept_mesh(scene, folder / "mesh.npz")
    probes = probe_points(read_mesh(study / "mesh_1.npz"), scene)
    tip = np.asarray(scene.guide.tip_mm)
    near_probe = np.linalg.norm(probes["prostate_surface"] - tip, axis=1) < NEAR_TIP_MM
    surface = np.asarray(mesh.node_sets["prostate_surface"])
    near_own = np.linalg.norm(mesh.nodes[surface] - tip, axis=1) < NEAR_TIP_MM
    problem = build_problem(scene, mesh)
    named = {"max": mx, "prostate": prostate, "guide": guide} | ({"surface_near_tip": shell} if shell else {})
    row = {"sizes_mm": named, "n_tets": len(mesh.tets),
           "n_nodes": len(mesh.nodes), "cases": {}}
    for d, beta in cases:
        logging.info("sizes %s (%d tets): %g mm, %g deg", tag(sizes), len(mesh.tets), d, beta)
        u, seconds = solve_resumable(problem, d, beta, folder / f"path_{d:g}_{beta:g}.npz")
        used, u1, band, order = converged_estimate(study, scales, (d, beta), mesh.nodes)
        e_own = np.linalg.norm(u - u1, axis=1) + band
        at, bands = {}, {}
        for k in ("markers", "interior", "prostate_surface", "nodes"):
            _, p1, bands[k], _ = converged_estimate(study, scales, (d, beta), probes[k], order)
            at[k] = np.linalg.norm(at_points(mesh, u, probes[k]) - p1, axis=1) + bands[k]
        surface_band = bands["prostate_surface"]
        rest = np.flatnonzero(~near_probe)
        worst = rest[np.argmax(at["prostate_surface"][rest])]
        row["cases"][f"{d:g} mm, {beta:g} deg"] = {
            "seconds": seconds, "levels": used,
            "markers_mm": float(at["markers"].max()), "interior_mm": float(at["interior"].max()),
            "surface_probes_mm": {"max": float(at["prostate_surface"].max()),
                                  "near_tip_max": float(at["prostate_surface"][near_probe].max()),
                                  "rest_max": float(at["prostate_surface"][~near_probe].max())},
            # the bound is this mesh's gap to the fine level plus the fine level's own band: no mesh gets under the band
            "surface_probes_band_mm": {"near_tip_max": float(surface_band[near_probe].max()),
                                       "rest_max": float(surface_band[~near_probe].max())},
            "surface_rest_worst": {"band_mm": float(surface_band[worst]),
                                   "gap_mm": float(at["prostate_surface"][worst] - surface_band[worst]),
                                   "to_tip_mm": float(np.linalg.norm(probes["prostate_surface"][worst] - tip)),
                                   "point_mm": probes["prostate_surface"][worst].round(2).tolist()},
            "surface_own_nodes_mm": {"max": float(e_own[surface].max()),
                                     "near_tip_max": float(e_own[surface[near_own]].max()),
                                     "rest_max": float(e_own[surface[~near_own]].max())},
            "all_nodes_mm": float(e_own.max()), "all_nodes_probes_mm": float(at["nodes"].max())}
    return row


def parser() -> argparse.ArgumentParser:
    ap = study_parser("python -m studies graded-mesh", __doc__)
    ap.add_argument("--sizes", type=sizes_arg, nargs="+", required=True, metavar="MAX:PROSTATE:GUIDE[:SURFACE]")
    add_scene_flag(ap)
    add_study_flags(ap)
    add_cases_flag(ap)
    ap.add_argument("--out", type=Path, default=Path("runs/graded"))
    results.add_publish_flag(ap)
    return ap


def main(argv: list[str] | None = None) -> int | None:
    args = parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    cases = tuple(args.cases or HARD_CASES)
    try:
        if not (args.study / "mesh_1.npz").exists():
            raise FileNotFoundError(f"--study: {args.study / 'mesh_1.npz'} not found (run the convergence study first)")
        for case in cases:  # refuse before any solving
            case_levels(args.study, args.scales, case)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    scene = study_scene(args.scene, contact=True, step_mm=0.5, volumetric="taylor_hood")
    t0 = time.perf_counter()
    folder = results.DOCS_RESULTS if args.publish else results.RUNS_RESULTS
    previous = results.read("graded_mesh", folder) if (folder / "graded_mesh.json").exists() else {}
    meshes = {m["tag"]: m for m in previous.get("meshes", [])}
    for sizes in tqdm(args.sizes, desc="graded meshes", unit="mesh"):
        row = judge(scene, sizes, args.study, args.scales, cases, args.out)
        meshes[tag(sizes)] = {"tag": tag(sizes), "command": command(sizes, args, cases), **row}
        for case, r in row["cases"].items():
            worst = r["surface_rest_worst"]
            print(f"sizes {tag(sizes)} ({row['n_tets']} tets), {case} ({r['seconds'] / 60:.1f} min): vs converged, "
                  f"markers {r['markers_mm']:.3f} mm, interior {r['interior_mm']:.3f}, surface at the study's points "
                  f"{r['surface_probes_mm']['max']:.3f} (near tip {r['surface_probes_mm']['near_tip_max']:.3f}, rest "
                  f"{r['surface_probes_mm']['rest_max']:.3f}: gap {worst['gap_mm']:.3f} + the estimate's band "
                  f"{worst['band_mm']:.3f} at {worst['to_tip_mm']:.1f} mm from the tip), at its own nodes "
                  f"{r['surface_own_nodes_mm']['max']:.3f}, every node {r['all_nodes_mm']:.3f}", flush=True)
    ordered = sorted(meshes.values(), key=lambda m: m["n_tets"])
    result = {"kind": "graded_mesh", "study": str(args.study), "scales": args.scales,
              # the file merges runs: each mesh names the command that judged it, and these are all of them
              "commands": list(dict.fromkeys(m["command"] for m in ordered if "command" in m)),
              "meshes": ordered}
    path = results.write("graded_mesh", result, publish=args.publish)
    print(f"wrote {path} ({time.perf_counter() - t0:.0f} s this run)")
    return 0
