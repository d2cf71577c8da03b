"""Label map -> one conforming tet mesh, a tissue per tet, in the image's patient coordinates (mm).

    voxels --(scene's label table)--> tissue per voxel --(surface nets: smoothed interfaces)-->
    triangles on every tissue interface --(fTetWild or TetGen)--> tets filling the image box,
    each given the tissue its centroid lies in --> corner tets for mesh.from_vertices

Surface nets (VTK) put one shared, conforming triangle surface on every interface between two
labels and smooth it: each vertex stays within `CONSTRAINT_VOXELS` of its voxel-boundary position,
which removes the staircase. fTetWild embeds those triangles into a tet mesh sized like the
phantom's (fine at the prostate and the guide), so every tet lies on one side of every interface
and the tissues share nodes (bonded). Nodes within a quarter voxel of the image's box are put on
it: a body surface there is a cut of the image, flat, and the table (z = z_min) stays one plane.
The candidates and how they were chosen: scripts/compare_meshers.py and the README.
"""

from __future__ import annotations

import ctypes
import logging
import os
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from .labelmap import OUTSIDE, LabelImage, read_label_map
from .scene import Guide, LabelMap, MeshSize, Scene

log = logging.getLogger(__name__)

FACET_DISTANCE_VOXELS = 0.5  # CGAL: how far a surface facet may stray from the labels' boundary
CONSTRAINT_VOXELS = 0.75  # how far surface-nets smoothing may move a vertex from its voxel-boundary position
SMOOTHING_ITERATIONS = 32
ENVELOPE_VOXELS = 0.1  # fTetWild's envelope: how far the tet faces may stray from the smoothed surface


@contextmanager
def _quiet_native_output():
    """Send file descriptors 1 and 2 to /dev/null (CGAL's C++ progress output), then restore them."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with open(os.devnull, "wb") as null:
        os.dup2(null.fileno(), 1)
        os.dup2(null.fileno(), 2)
        try:
            yield
        finally:
            ctypes.CDLL(None).fflush(None)  # what C/C++ buffered goes to /dev/null, not out after the restore
            for fd, copy in zip((1, 2), saved):
                os.dup2(copy, fd)
                os.close(copy)


@dataclass(frozen=True)
class VoxelTissues:
    index: np.ndarray  # (ni, nj, nk) int8: tissue index into names, OUTSIDE (-1) where not tissue
    names: tuple[str, ...]
    image: LabelImage


def voxel_tissues(image: LabelImage, spec: LabelMap) -> VoxelTissues:
    """The tissue of each voxel from the scene's label table; ValueError naming the field for an unknown or empty label."""
    values, counts = np.unique(image.labels, return_counts=True)
    present = dict(zip(values.tolist(), counts.tolist()))
    known = set(spec.labels.values()) | set(spec.outside) | {0}
    unknown = sorted(set(present) - known)
    if unknown:
        raise ValueError(f"label_map.labels: {spec.path.name} holds label values {unknown} that are neither in "
                         f"label_map.labels nor in label_map.outside")
    empty = [f"{name} = {v}" for name, v in spec.labels.items() if present.get(v, 0) == 0]
    if empty:
        raise ValueError(f"label_map.labels: no voxel of {spec.path.name} has the label of {', '.join(empty)}")
    names = spec.tissue_names
    lut = np.full(max(known) + 1, OUTSIDE, dtype=np.int8)
    for name, v in spec.labels.items():
        lut[v] = names.index(name)
    if spec.background:
        lut[0] = names.index(spec.background)
    index = lut[image.labels]
    if not (index >= 0).any():
        raise ValueError(f"label_map: {spec.path.name} has no tissue voxel")
    return VoxelTissues(index, names, image)


def surface_nets(index: np.ndarray, *, iterations: int = SMOOTHING_ITERATIONS,
                 constraint_voxels: float = CONSTRAINT_VOXELS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smoothed interface triangles of a tissue-index volume: vertices (n, 3) in voxel index
    coordinates, triangles (m, 3), the two tissues each triangle separates (m, 2; OUTSIDE = -1).

    The volume is padded with one layer of OUTSIDE, so the image's box is an interface too.
    """
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    padded = np.pad(index.astype(np.int16) + 1, 1)  # 0 = outside, tissue t = t + 1
    img = vtk.vtkImageData()
    img.SetDimensions(*padded.shape)
    img.SetOrigin(-1.0, -1.0, -1.0)  # so vertex coordinates are the unpadded voxel indices
    img.GetPointData().SetScalars(numpy_to_vtk(padded.ravel(order="F"), deep=True))
    nets = vtk.vtkSurfaceNets3D()
    nets.SetInputData(img)
    labels = np.unique(padded)
    for k, v in enumerate(labels[labels > 0]):
        nets.SetValue(k, int(v))
    nets.SetBackgroundLabel(0)
    nets.SetOutputMeshTypeToTriangles()
    nets.SetSmoothing(iterations > 0)
    nets.SetNumberOfIterations(iterations)
    nets.SetConstraintStrategyToConstraintDistance()
    nets.SetConstraintDistance(constraint_voxels)
    nets.Update()
    out = nets.GetOutput()
    points = vtk_to_numpy(out.GetPoints().GetData()).astype(np.float64)
    tris = vtk_to_numpy(out.GetPolys().GetConnectivityArray()).reshape(-1, 3).astype(np.int64)
    pairs = vtk_to_numpy(out.GetCellData().GetArray("BoundaryLabels")).reshape(-1, 2).astype(np.int64) - 1
    return points, tris, pairs


def size_mm(points_mm: np.ndarray, *, tissues: VoxelTissues, size: MeshSize, guide: Guide) -> np.ndarray:
    """Target edge length (k,) at points (k, 3): the phantom's size field (phantom._size_field), from the voxels.

    prostate_mm at the prostate, growing linearly to max_mm 25 mm away; guide_mm within 1.5
    patch radii of the tip, max_mm beyond 3.5 (the Ball field's VIn/VOut with its thickness).
    """
    from scipy.ndimage import distance_transform_edt

    image = tissues.image
    prostate = tissues.index == tissues.names.index("prostate") if "prostate" in tissues.names else None
    size_at = np.full(len(points_mm), size.max_mm)
    if prostate is not None:
        dist = distance_transform_edt(~prostate, sampling=image.spacing_mm)
        ijk = np.clip(np.rint(image.to_index(points_mm)).astype(int), 0, np.array(prostate.shape) - 1)
        d = dist[tuple(ijk.T)]
        size_at = np.minimum(size_at, size.prostate_mm + (size.max_mm - size.prostate_mm) * np.clip(d / 25.0, 0, 1))
    r = np.linalg.norm(points_mm - np.asarray(guide.tip_mm), axis=1)
    inner, thickness = 1.5 * guide.patch_radius_mm, 2.0 * guide.patch_radius_mm
    ball = size.guide_mm + (size.max_mm - size.guide_mm) * np.clip((r - inner) / thickness, 0, 1)
    return np.minimum(size_at, ball)


def box_grid(lo: np.ndarray, hi: np.ndarray, step_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """A Kuhn (6 tets per cell) tet grid of the box [lo, hi]: points (n, 3), tets (m, 4)."""
    counts = np.maximum(np.ceil((hi - lo) / step_mm).astype(int), 1)
    axes = [np.linspace(a, b, n + 1) for a, b, n in zip(lo, hi, counts)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    shape = counts + 1
    corner = np.stack(np.meshgrid(*(np.arange(n) for n in counts), indexing="ij"), axis=-1).reshape(-1, 3)
    ids = lambda off: np.ravel_multi_index((corner + off).T, shape)  # noqa: E731
    c = [ids(np.array([(v >> 0) & 1, (v >> 1) & 1, (v >> 2) & 1])) for v in range(8)]
    kuhn = [(0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)]
    tets = np.concatenate([np.stack([c[a], c[b], c[d], c[e]], axis=1) for a, b, d, e in kuhn])
    return points, tets


def _ftetwild(vertices_mm, triangles, *, size_at, epsilon_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """fTetWild on the interface triangles, sized by size_at(points); every tet of the box is kept."""
    import pytetwild

    lo, hi = vertices_mm.min(axis=0), vertices_mm.max(axis=0)
    bg_points, bg_tets = box_grid(lo - 1.0, hi + 1.0, 2.0)
    diagonal = float(np.linalg.norm(hi - lo))
    points, tets = pytetwild.tetrahedralize(
        vertices_mm, triangles.astype(np.int32), edge_length_abs=float(size_at(bg_points).max()),
        epsilon=epsilon_mm / diagonal, disable_filtering=True, num_threads=1, quiet=True,
        bg_vertices=bg_points, bg_tets=bg_tets.astype(np.int32), bg_values=size_at(bg_points))
    return np.asarray(points, dtype=np.float64), np.asarray(tets, dtype=np.int64)


def _cgal(tissues: VoxelTissues, *, size: MeshSize, guide: Guide) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CGAL's labelled-image mesher (pygalmesh): points (n, 3) in voxel index coordinates, tets (m, 4), tissue (m,).

    Cell sizes are per label, so the guide's fine ball is a label of its own (the tissue's voxels
    within 1.5 patch radii of the tip), merged back into its tissue after meshing.
    """
    import pygalmesh

    image, n = tissues.image, len(tissues.names)
    sub = tissues.index.astype(np.int16) + 1  # CGAL: 0 = outside, tissue t = t + 1
    shape = np.array(sub.shape)
    centres = image.to_physical(np.stack(np.meshgrid(*(np.arange(k) for k in shape), indexing="ij"), -1).reshape(-1, 3))
    near_tip = (np.linalg.norm(centres - np.asarray(guide.tip_mm), axis=1) < 1.5 * guide.patch_radius_mm).reshape(sub.shape)
    near_tip &= sub > 0
    sub[near_tip] += n  # tissue t near the tip = t + 1 + n
    sizes = {t + 1: (size.prostate_mm if name == "prostate" else size.max_mm) for t, name in enumerate(tissues.names)}
    sizes.update({t + 1 + n: size.guide_mm for t in range(n)})
    spacing = tuple(float(s) for s in image.spacing_mm)
    with _quiet_native_output():  # CGAL prints its progress whatever `verbose` says
        mesh = pygalmesh.generate_from_array(
            np.pad(sub, 1).astype(np.uint8), spacing, max_cell_circumradius=sizes,
            max_facet_distance=FACET_DISTANCE_VOXELS * float(min(spacing)), max_radius_surface_delaunay_ball=size.prostate_mm,
            min_facet_angle=25.0, max_circumradius_edge_ratio=3.0, verbose=False, seed=0)
    tets = mesh.get_cells_type("tetra").astype(np.int64)
    label = mesh.get_cell_data("medit:ref", "tetra").astype(np.int64)
    points = mesh.points / np.asarray(spacing) - 1.0  # CGAL puts voxel i's centre at i * spacing; one pad layer
    return points, tets, (label - 1) % n











def snap_to_box(points_index: np.ndarray, shape, tol_voxels: float = 0.25) -> np.ndarray:
    """Put points within tol_voxels of the image box (voxel index coordinates) exactly on its faces."""
    lo, hi = np.full(3, -0.5), np.asarray(shape, dtype=np.float64) - 0.5
    p = points_index.copy()
    p = np.where(np.abs(p - lo) < tol_voxels, lo, p)
    return np.where(np.abs(p - hi) < tol_voxels, hi, p)


MESHERS = {"cgal": _cgal}


def mesh_label_map(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[str, ...]]:
    """Mesh the scene's label map: nodes (n, 3) RAS mm, corner tets (m, 4), tissue (m,), tissue names."""
    spec = scene.label_map
    image = read_label_map(spec.path)
    tissues = voxel_tissues(image, spec)
    if spec.mesher not in MESHERS:
        raise ValueError(f"label_map.mesher: {spec.mesher!r} is measured by scripts/compare_meshers.py "
                         f"but not built in; use one of {sorted(MESHERS)}")
    t0 = time.perf_counter()
    points, tets, tissue = MESHERS[spec.mesher](tissues, size=scene.mesh, guide=scene.guide)
    points = image.to_physical(snap_to_box(points, image.labels.shape))
    log.info("label map %s: %d tets, %d vertices by %s in %.1f s", spec.path.name, len(tets), len(points),
             spec.mesher, time.perf_counter() - t0)
    return points, tets, tissue, tissues.names
