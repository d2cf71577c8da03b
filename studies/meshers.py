"""Label-map meshers measured on a voxelised phantom: validity, quality, tissue volumes, conformity, the linear FE.

The phantom's exact geometry is the reference: tissue volumes from `reference_volumes`, and the
linear answer (guide glued to its patch) at the gmsh phantom mesh's 8 markers for one push (10 mm, beta = 0).
`python -m studies compare-meshers` prints these and writes the result meshers
(runs/results/, or docs/results/ with --publish).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from fem_offline.labelmap.io import write_label_map
from fem_offline.labelmap.quality import (face_owner_counts, min_dihedral_deg, radius_ratio, signed_volumes,
                                          tissue_volumes)
from fem_offline.scene import Scene, parse_scene
from studies.phantom_labelmap import labelmap_scene, linear_markers, reference_volumes, voxelise

log = logging.getLogger(__name__)

DEGENERATE_RADIUS_RATIO = 1e-3  # q = 3 r_in / r_circ below this: a sliver no P2 element should be built on
PUSH = {"displacement_mm": 10.0, "angle_deg": 0.0}


def glued(scene: Scene) -> Scene:
    """The scene with the guide glued to its wall patch: the linear model is a superposition only then (sweep.py)."""
    return scene.model_copy(update={"effects": scene.effects.model_copy(update={"guide_contact": False})})


def label_map_scene(phantom_scene: Scene, spacing_mm: float, folder: Path, *, mesher: str = "cgal") -> Scene:
    """Voxelise the phantom at spacing_mm into folder/labels.nii.gz; the label-map scene that reads it with `mesher`."""
    folder.mkdir(parents=True, exist_ok=True)
    write_label_map(folder / "labels.nii.gz", voxelise(phantom_scene.phantom, spacing_mm))
    data = labelmap_scene(phantom_scene, str(folder / "labels.nii.gz"))
    data["label_map"]["mesher"] = mesher
    return parse_scene(data)


def corner_mesh_report(points: np.ndarray, tets: np.ndarray, tissue: np.ndarray, names,
                       exact: dict[str, float]) -> dict[str, Any]:
    """Validity, quality, volume errors (fraction of the exact volume) and conformity of corner tets (m, 4)
    as the mesher left them.

    Inverted: tets whose orientation is against the majority's (a mesher orients consistently).
    """
    vol = signed_volumes(points, tets)
    majority = np.sign(np.median(vol))
    q = radius_ratio(points, tets)
    owners = face_owner_counts(tets)
    volumes = tissue_volumes(points, tets, tissue, names)
    return {
        "tets": int(len(tets)), "vertices": int(len(np.unique(tets))),
        "inverted": int((np.sign(vol) != majority).sum()),
        "degenerate": int((q < DEGENERATE_RADIUS_RATIO).sum()),
        "min_dihedral_deg": float(np.nanmin(min_dihedral_deg(points, tets))),
        "min_radius_ratio": float(q.min()),
        "volume_error": {name: float(volumes[name] / exact[name] - 1.0) for name in names},
        "faces_with_three_owners": int((owners > 2).sum()),
    }


def voxel_boundary_distance_mm(points_mm: np.ndarray, image, inside: np.ndarray) -> np.ndarray:
    """Distance (k,) mm from points (k, 3) RAS to the staircase boundary of a voxel mask (the union of the
    voxel faces between `inside` and the rest): exact distance to the 16 nearest faces' squares."""
    from scipy.spatial import cKDTree

    centres, normal_axis = [], []
    padded = np.pad(inside, 1)
    for a in range(3):
        lo = padded[tuple(slice(0, -1) if k == a else slice(None) for k in range(3))]
        hi = padded[tuple(slice(1, None) if k == a else slice(None) for k in range(3))]
        face = np.argwhere(lo != hi).astype(np.float64) - 1.0  # voxel p, p + e_a in image indices
        face[:, a] += 0.5
        centres.append(face)
        normal_axis.append(np.full(len(face), a))
    centres, normal_axis = np.concatenate(centres), np.concatenate(normal_axis)
    spacing = image.spacing_mm
    q = image.to_index(points_mm)
    _, near = cKDTree(centres * spacing).query(q * spacing, k=16)
    d = (q[:, None, :] - centres[near]) * spacing  # (k, 16, 3) offsets from each face centre, mm
    in_plane = np.arange(3)[None, None, :] != normal_axis[near][:, :, None]
    d = np.where(in_plane, np.maximum(np.abs(d) - 0.5 * spacing, 0.0), d)  # beyond the square's half-width
    return np.linalg.norm(d, axis=2).min(axis=1)


def surface_to_voxels(points: np.ndarray, tets: np.ndarray, tissue: np.ndarray, names, image, tissue_name: str,
                      voxel_tissue: np.ndarray) -> dict[str, float]:
    """How far the meshed surface of one tissue lies from its voxels' staircase boundary: max and mean over
    the surface's vertices, edge midpoints and face centroids, mm and voxels."""
    from contracts.tet10 import FACES

    t = names.index(tissue_name)
    faces = np.sort(tets[tissue == t][:, FACES].reshape(-1, 3), axis=1)
    unique, count = np.unique(faces, axis=0, return_counts=True)
    surface = unique[count == 1]  # (f, 3) faces with one tet of this tissue
    p = points[surface]
    samples = np.concatenate([points[np.unique(surface)], p.mean(axis=1),
                              0.5 * (p[:, [0, 1, 2]] + p[:, [1, 2, 0]]).reshape(-1, 3)])
    d = voxel_boundary_distance_mm(samples, image, voxel_tissue == t)
    voxel = float(image.spacing_mm.min())
    return {"max_mm": float(d.max()), "mean_mm": float(d.mean()), "max_voxels": float(d.max() / voxel),
            "mean_voxels": float(d.mean() / voxel)}


REFINEMENT = 1.3  # the convergence study's ratio: the gmsh phantom one level finer, for its own discretisation change


def phantom_markers(phantom_scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The gmsh phantom mesh's 8 marker positions (8, 3) mm, its linear displacement there (8, 3) mm for
    PUSH, and that of the gmsh phantom with every size / REFINEMENT (8, 3): how much the answer at the
    markers still moves with the mesh, the yardstick for the label-map meshes' difference."""
    from fem_offline.geometry.meshing import mesh_for_scene

    mesh = mesh_for_scene(phantom_scene)
    points = mesh.nodes[mesh.node_sets["markers"]]
    sizes = {k: v / REFINEMENT for k, v in phantom_scene.mesh.model_dump().items() if v is not None}
    finer_scene = phantom_scene.model_copy(update={"mesh": phantom_scene.mesh.model_copy(update=sizes)})
    finer = mesh_for_scene(finer_scene)
    return (points, linear_markers(glued(phantom_scene), mesh, points, **PUSH),
            linear_markers(glued(finer_scene), finer, points, **PUSH))


def measure(scene: Scene, *, exact: dict[str, float], markers_mm: np.ndarray, reference_u: np.ndarray,
            max_solve_tets: int) -> dict[str, Any]:
    """Mesh a label-map scene, report the corner mesh, then the P2 linear solve at the markers against the
    phantom's (not above max_solve_tets: TetGen's 0.5 mm mesh, 253,040 tets, ran past 13 min on 2 shared cores)."""
    from fem_offline.labelmap.meshers import mesh_label_map
    from fem_offline.geometry.mesh import from_vertices
    from fem_offline.geometry.regions import build_node_sets

    from fem_offline.labelmap.io import read_label_map
    from fem_offline.labelmap.meshers import voxel_tissues

    t0 = time.perf_counter()
    points, tets, tissue, names = mesh_label_map(scene)
    report = {"mesher": scene.label_map.mesher, "seconds": time.perf_counter() - t0,
              **corner_mesh_report(points, tets, tissue, names, exact)}
    image = read_label_map(scene.label_map.path)
    report["prostate_surface_to_voxels"] = surface_to_voxels(
        points, tets, tissue, names, image, "prostate", voxel_tissues(image, scene.label_map).index)
    if len(tets) > max_solve_tets:
        report["linear_solve"] = f"not run: {len(tets)} tets > {max_solve_tets}"
        return report
    try:
        mesh = build_node_sets(from_vertices(points, tets, tissue, names), scene)
        u = linear_markers(glued(scene), mesh, markers_mm, **PUSH)
    except Exception as exc:  # noqa: BLE001 -- the report says how the solve failed
        report["linear_solve"] = f"fails: {type(exc).__name__}: {exc}"
        return report
    diff = np.linalg.norm(u - reference_u, axis=1)
    report.update(linear_solve="runs", marker_u_mm=np.linalg.norm(u, axis=1).tolist(),
                  marker_difference_mm=diff.tolist(), marker_difference_max_mm=float(diff.max()))
    return report


def study(phantom_scene: Scene, *, spacings_mm, meshers, folder: Path, max_solve_tets: int = 150_000,
          on_row=lambda result: None) -> dict[str, Any]:
    """Every mesher at every spacing on the phantom's label map, against its exact volumes and the gmsh
    mesh's linear markers; on_row(result so far) after each."""
    exact = reference_volumes(phantom_scene.phantom, 0.25)
    markers, ref, finer = phantom_markers(phantom_scene)
    result = {"scene": phantom_scene.name, "mesh_sizes_mm": phantom_scene.mesh.model_dump(), "push": PUSH,
              "phantom_marker_u_mm": np.linalg.norm(ref, axis=1).tolist(),
              "phantom_refined_marker_difference_mm": np.linalg.norm(finer - ref, axis=1).tolist(), "rows": []}
    for spacing in spacings_mm:
        for mesher in meshers:
            scene = label_map_scene(phantom_scene, spacing, folder / f"{spacing:g}mm", mesher=mesher)
            log.info("meshing the %g mm label map with %s", spacing, mesher)
            row = measure(scene, exact=exact, markers_mm=markers, reference_u=ref, max_solve_tets=max_solve_tets)
            result["rows"].append({"spacing_mm": spacing, **row})
            on_row(result)
    return result
