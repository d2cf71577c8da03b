"""A label map of the parametric phantom: the fixture that stands in for a patient's segmentation.

Studies and tests share it; it is not library code (linear_markers runs the linear solver), so it lives here,
beside the studies that measure label-map meshes against the phantom.

Each voxel takes the tissue at its centre, with phantom.py's priority where shapes overlap. The image
covers the phantom's block exactly, so its volume is the block's; the rectal lumen is its own label,
outside the body. The voxel grid has a non-trivial origin and direction (a signed permutation:
patient axes stay axis-aligned, so the table stays at z = 0), and its patient coordinates (RAS, mm)
are the phantom's own, so a mesh of the label map and the phantom's gmsh mesh can be compared node
for node.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fem_offline.labelmap.io import LabelImage
from fem_offline.scene import Phantom, Scene

# Label values, as a segmentation exported from 3D Slicer would number its segments.
LABELS = {"prostate": 1, "rectal_wall": 2, "bladder": 3, "pubic_bone": 4, "spine": 5}
LUMEN = 6
# Index axis i, j, k -> patient axis (columns): i runs along -x, j along +z, k along +y, as in a
# sagittal series; det = +1 keeps the handedness of patient space.
DIRECTION = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])


def grid(phantom: Phantom, spacing_mm: float, direction: np.ndarray = DIRECTION) -> tuple[tuple[int, ...], np.ndarray]:
    """(shape, affine (4, 4)) of a voxel grid covering the block [-bx/2, bx/2] x [-by/2, by/2] x [0, bz]."""
    size = np.asarray(phantom.block_mm)
    counts = np.round(size / spacing_mm).astype(int)
    if not np.allclose(counts * spacing_mm, size, atol=1e-9):
        raise ValueError(f"--spacing-mm: {spacing_mm} does not divide the block {list(phantom.block_mm)} mm")
    lo = np.array([-size[0] / 2, -size[1] / 2, 0.0])
    step = direction * spacing_mm  # column a: the step of index axis a
    axis_of = np.abs(direction).argmax(axis=0)  # the patient axis each index axis runs along
    shape = tuple(int(counts[a]) for a in axis_of)
    # The voxel (0, 0, 0) sits at the corner where every index axis starts: +x end for i (it runs to -x).
    first = lo + 0.5 * spacing_mm + (direction.sum(axis=1) < 0) * (size - spacing_mm)
    affine = np.eye(4)
    affine[:3, :3], affine[:3, 3] = step, first
    return shape, affine


def tissue_at(phantom: Phantom, p: np.ndarray) -> np.ndarray:
    """Label value (k,) at points p (k, 3): 0 adipose, LUMEN, or a LABELS value;
    phantom.PRIORITY where shapes overlap."""
    x, y, z = p.T
    ph = phantom
    out = np.zeros(len(p), dtype=np.uint8)
    rx, ry = ph.rectum_center_xy_mm
    r2 = (x - rx) ** 2 + (y - ry) ** 2
    out[r2 < ph.rectum_outer_radius_mm**2] = LABELS["rectal_wall"]
    out[r2 < ph.rectum_inner_radius_mm**2] = LUMEN
    out[np.sum((p - ph.bladder_center_mm) ** 2, axis=1) < ph.bladder_radius_mm**2] = LABELS["bladder"]
    out[np.sum(((p - ph.prostate_center_mm) / ph.prostate_semi_axes_mm) ** 2, axis=1) < 1] = LABELS["prostate"]
    lo, hi = np.asarray(ph.spine_box_mm)
    out[np.all((p > lo) & (p < hi), axis=1)] = LABELS["spine"]
    px, py, pz = ph.pubic_center_mm
    bar = (np.abs(x - px) < ph.pubic_length_mm / 2) & ((y - py) ** 2 + (z - pz) ** 2 < ph.pubic_radius_mm**2)
    out[bar] = LABELS["pubic_bone"]
    return out


def voxelise(phantom: Phantom, spacing_mm: float, direction: np.ndarray = DIRECTION) -> LabelImage:
    """The phantom as a label map at `spacing_mm`, each voxel the tissue at its centre."""
    shape, affine = grid(phantom, spacing_mm, direction)
    index = np.stack(np.meshgrid(*(np.arange(n) for n in shape), indexing="ij"), axis=-1).reshape(-1, 3)
    labels = tissue_at(phantom, index @ affine[:3, :3].T + affine[:3, 3])
    return LabelImage(labels.reshape(shape), affine)


def labelmap_scene(scene: Scene, label_map_path: str, *, name: str | None = None) -> dict[str, Any]:
    """A label-map scene (TOML data) equivalent to a phantom scene: same tissues, guide, effects, sweep, sizes."""
    data = scene.model_dump(mode="json", exclude_none=True)
    data.pop("phantom", None)
    if scene.guide.snap_mm is None:  # the phantom's exact tip: the label map's seat takes its defaults (Scene)
        data["guide"].pop("snap_to", None)
    data["name"] = name or f"{scene.name}_labelmap"
    data["label_map"] = {"path": label_map_path, "labels": dict(LABELS), "background": "adipose", "outside": [LUMEN]}
    return data


def reference_volumes(phantom: Phantom, spacing_mm: float = 0.2) -> dict[str, float]:
    """Tissue volumes (mm^3) of the exact phantom geometry, by voxel centres at spacing_mm, one z slice at a time."""
    bx, by, bz = phantom.block_mm
    xs = np.arange(-bx / 2, bx / 2, spacing_mm) + spacing_mm / 2
    ys = np.arange(-by / 2, by / 2, spacing_mm) + spacing_mm / 2
    x, y = (a.ravel() for a in np.meshgrid(xs, ys, indexing="ij"))
    counts = np.zeros(LUMEN + 1)
    for z in np.arange(0, bz, spacing_mm) + spacing_mm / 2:
        counts += np.bincount(tissue_at(phantom, np.stack([x, y, np.full_like(x, z)], axis=1)), minlength=LUMEN + 1)
    volumes = {"adipose": counts[0], **{name: counts[v] for name, v in LABELS.items()}}
    return {name: float(c * spacing_mm**3) for name, c in volumes.items()}


def linear_markers(scene: Scene, mesh, points_mm: np.ndarray, *, displacement_mm: float,
                   angle_deg: float) -> np.ndarray:
    """Linear-model displacement (k, 3) mm at points (k, 3) for one guide push, P2-interpolated on `mesh`."""
    from contracts.interpolate import interpolation_matrix

    from fem_offline.fe.linear import linear_modes, superpose
    from fem_offline.fe.problem import build_problem

    linear = scene.model_copy(update={"effects": scene.effects.model_copy(update={"geometric_nonlinearity": False})})
    u = superpose(linear_modes(build_problem(linear, mesh)), displacement_mm, angle_deg)
    return interpolation_matrix(mesh.nodes, mesh.tets, points_mm, nearest=True) @ u
