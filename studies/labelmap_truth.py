"""The patient pipeline's FE against the converged estimate: the default phantom as a label map.

    python -m studies labelmap-truth [--spacing-mm 1] [--mesher cgal] [--facet-distance-voxels 0.5 1] [--volumetric E] \\
        [--work runs/labelmap_truth] [--study runs/convergence_contact_taylor_hood] [--scales 1.3 1 0.769 0.5917] \\
        [--publish]

A patient model's FE error has two parts that a grid-convergence study of the phantom does not see:
the voxels (the tissue surfaces are a label map's staircase, smoothed) and the label-map mesher's
tets. This measures both at once where the converged answer is known. The default phantom is
voxelised (`python -m studies make-labelmap`'s generator), meshed from its labels with the patient defaults
(fem_offline/scenes/patient.toml: the default's mesh sizes, physics and element) and solved at the
grid-convergence study's hardest case (10 mm, beta = 0, from rest in 0.5 mm steps as the study). Its
displacement is compared with the converged estimate of the Taylor-Hood study (`make fe-error-taylor-hood`;
meshes and solutions read from --study; studies.convergence.converged_estimate) at the study's probe
points: the 8 markers, the 3 interior points and the scale-1 mesh's prostate-surface nodes. The error
against the converged estimate is at most |u_labelmap - u_finest| + the finest level's GCI band, point by
point; the same bound for the phantom's own gmsh mesh at the same sizes (the study's scale-1 level) is
printed beside it. --volumetric solves with another element than patient.toml's (solver.volumetric). Rows
are kept per voxel size, mesher, facet distance and element; one measured again replaces the old row (each
row names the study it was judged against: rows of earlier rounds, against the pointwise element's study).
The phantom is grid_study_base.toml's (the study's scene). The result labelmap_truth goes to runs/results/;
with --publish to docs/results/ and to the pipeline's package copy, pipeline/data/labelmap_fe_error.json
(the patient build's default FE estimate), so that the two never differ.
"""  # noqa: E501 -- argparse prints this docstring as it is (--help)

from __future__ import annotations

import argparse
import logging
import shutil
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from contracts.cli import number
from studies import results
from studies.options import GRID_STUDY_SCENE, SCENES, add_study_flags

PACKAGE_COPY = results.ROOT / "pipeline" / "data" / "labelmap_fe_error.json"

CASE = (10.0, 0.0)
CASE_KEY = "10 mm, 0 deg"


def label_map_scene(*, spacing_mm: float, mesher: str, facet_voxels: float | None, volumetric: str, folder: Path):
    """The default phantom voxelised at spacing_mm into `folder`, and its label-map scene (patient.toml's settings)."""
    import tomli_w

    from fem_offline.labelmap.io import write_label_map
    from studies.phantom_labelmap import labelmap_scene, voxelise
    from fem_offline.scene import load_scene

    phantom = load_scene(GRID_STUDY_SCENE)
    folder.mkdir(parents=True, exist_ok=True)
    labels = folder / "labels.nii.gz"
    if not labels.exists():
        write_label_map(labels, voxelise(phantom.phantom, spacing_mm))
    data = labelmap_scene(phantom, labels.name, name=f"default_labelmap_{spacing_mm:g}mm")
    data["label_map"]["mesher"] = mesher
    if mesher == "cgal":
        data["label_map"]["facet_distance_voxels"] = facet_voxels
    base = load_scene(SCENES / "patient.toml")  # the patient build's sweep and solver; the study's 0.5 mm steps
    data["sweep"] = base.sweep.model_dump(mode="json")
    data["solver"] = base.solver.model_dump(mode="json") | {"max_step_mm": 0.5, "volumetric": volumetric}
    (folder / "scene.toml").write_text(tomli_w.dumps(data))
    return load_scene(folder / "scene.toml")


def main(argv: list[str] | None = None) -> int | None:
    from fem_offline.scene import VOLUMETRIC

    ap = argparse.ArgumentParser(prog="python -m studies labelmap-truth", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacing-mm", type=number("--spacing-mm", minimum=0.05), nargs="+", default=[1.0])
    ap.add_argument("--mesher", default="cgal", choices=("cgal", "tetgen"))
    ap.add_argument("--facet-distance-voxels", type=number("--facet-distance-voxels", minimum=0.0), nargs="+",
                    default=[0.5], help="CGAL's label_map.facet_distance_voxels, one run each")
    ap.add_argument("--volumetric", choices=VOLUMETRIC,
                    help="the element (solver.volumetric; default: patient.toml's)")
    ap.add_argument("--work", type=Path, default=Path("runs/labelmap_truth"))
    add_study_flags(ap)
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")

    from contracts.mesh import read_mesh, write_mesh
    from studies.convergence import (at_points, case_levels, converged_estimate, level_solution, probe_points,
                                         solve_resumable)
    from fem_offline.geometry.meshing import load_or_build_mesh, mesh_for_scene
    from fem_offline.fe.problem import build_problem
    from fem_offline.scene import load_scene

    if not (args.study / "mesh_1.npz").exists():
        raise SystemExit(f"--study: {args.study / 'mesh_1.npz'} not found (run `make fe-error-taylor-hood` first)")
    try:
        used = case_levels(args.study, args.scales, CASE)
    except ValueError as exc:
        raise SystemExit(f"--study: {exc}") from None
    default = load_scene(GRID_STUDY_SCENE)
    # the study's probe points, taken from its scale-1 mesh (default.toml's sizes, as patient.toml's):
    # the 8 markers, the 3 interior points, its prostate-surface nodes; and the order of the case from every node
    default_mesh = read_mesh(args.study / "mesh_1.npz")
    probes = probe_points(default_mesh, default)
    _, _, _, order = converged_estimate(args.study, args.scales, CASE, probes.pop("nodes"))
    fine, band = {}, {}
    for k, p in probes.items():
        _, fine[k], band[k], _ = converged_estimate(args.study, args.scales, CASE, p, order)
    # the same bound for the phantom's own gmsh mesh at the same sizes (the study's scale-1 level), for comparison
    medium_bound = {k: float((np.linalg.norm(level_solution(args.study, 1.0, CASE, p) - fine[k], axis=1)
                              + band[k]).max())
                    for k, p in probes.items()}
    fine_tets = len(read_mesh(args.study / f"mesh_{used[-1]:g}.npz").tets)
    out = {"case": CASE_KEY, "rows": []}
    reference = {"study": str(args.study), "levels": used, "finest_level_tets": fine_tets,
                 "phantom_mesh_bound_mm": medium_bound}
    volumetric = args.volumetric or load_scene(SCENES / "patient.toml").solver.volumetric
    runs = [(s, f) for s in args.spacing_mm for f in (args.facet_distance_voxels if args.mesher == "cgal" else [None])]
    for spacing, facet in tqdm(runs, desc="label maps", unit="run"):
        # a folder per element: a path's checkpoints belong to its physics
        # (the pointwise rows' folders keep their names)
        folder = args.work / (f"{spacing:g}mm_{args.mesher}" + (f"_facet{facet:g}" if facet else "")
                              + ("" if volumetric == "pointwise" else f"_{volumetric}"))
        scene = label_map_scene(spacing_mm=spacing, mesher=args.mesher, facet_voxels=facet, volumetric=volumetric,
                                folder=folder)
        mesh_s = None  # None: meshed by an earlier run (the mesh is kept: the path's checkpoint belongs to it)
        if not (folder / "mesh.npz").exists():
            t0 = time.perf_counter()
            write_mesh(folder / "mesh.npz", mesh_for_scene(scene))
            mesh_s = time.perf_counter() - t0
        mesh = load_or_build_mesh(scene, folder / "mesh.npz")  # its node sets re-derived for the scene's guide
        u, seconds = solve_resumable(build_problem(scene, mesh), *CASE, folder / "path_10_0.npz")
        result = {"spacing_mm": spacing, "mesher": args.mesher, "facet_distance_voxels": facet,
                  "volumetric": scene.solver.volumetric, **reference, "tets": len(mesh.tets),
                  "nodes": len(mesh.nodes), "mesh_mm": scene.mesh.model_dump(), "mesh_s": mesh_s, "solve_s": seconds,
                  "regions": {}}
        facets = f" (facets {facet:g} voxel)" if facet else ""
        label = f"{spacing:g} mm voxels, {args.mesher}{facets}, {len(mesh.tets):,} tets"
        for k, p in probes.items():
            diff = np.linalg.norm(at_points(mesh, u, p) - fine[k], axis=1)
            bound = diff + band[k]
            result["regions"][k] = {"vs_finest_max_mm": float(diff.max()), "vs_finest_mean_mm": float(diff.mean()),
                                    "bound_max_mm": float(bound.max())}
            print(f"{label}: {k}: |u - u_finest| max "
                  f"{diff.max():.3f} mean {diff.mean():.3f} mm; vs converged <= {bound.max():.3f} mm "
                  f"(the default gmsh mesh: <= {medium_bound[k]:.3f} mm)", flush=True)
        print(f"  mesh {'kept' if mesh_s is None else f'{mesh_s:.1f} s'}, solve {seconds:.0f} s", flush=True)
        out["rows"].append(result)
    key = lambda r: (r["spacing_mm"], r["mesher"], r["facet_distance_voxels"], r["volumetric"])  # noqa: E731
    folder = results.DOCS_RESULTS if args.publish else results.RUNS_RESULTS
    # rows of earlier runs (other voxels, meshers, facets, elements) are kept
    if (folder / "labelmap_truth.json").exists():
        done = {key(r) for r in out["rows"]}
        out["rows"] = [r for r in results.read("labelmap_truth", folder)["rows"] if key(r) not in done] + out["rows"]
    out["rows"].sort(key=lambda r: (r["volumetric"] != "taylor_hood", r["mesher"], -r["spacing_mm"],
                                    -(r["facet_distance_voxels"] or 0)))
    path = results.write("labelmap_truth", out, publish=args.publish)
    if args.publish:  # the patient build reads the package copy: one file, never two versions
        shutil.copyfile(path, PACKAGE_COPY)
    print(f"wrote {path}" + (f" and {PACKAGE_COPY}" if args.publish else ""))
    return 0
