"""Label map -> one conforming tet mesh, a tissue per tet, in the image's patient coordinates (mm).

Three meshers (`label_map.mesher`), measured against each other by `python -m studies compare-meshers` (README):

- "cgal" (default): CGAL's labelled-image mesher (pygalmesh) meshes the voxel labels directly, cell
  size per label, the guide's fine ball a label of its own, facets within half a voxel of the labels'
  boundary. Best elements; needs a CGAL compile (`make labelmesh`).
- "tetgen": the interfaces as surface nets, smoothed and decimated (surface.py), are kept as
  they are (-Y) in TetGen's constrained Delaunay mesh; each closed region takes the tissue of most
  of its voxels. A wheel, so CI meshes label maps with it; it leaves slivers where four surface
  nodes are nearly coplanar.
- "ftetwild": fTetWild embeds the same surface with the phantom's size field; minutes per label map.

Boundary nodes within a quarter voxel of the image's box are put on it: a body surface there is a
cut of the image, flat, and the table (z = z_min) stays one plane; a tet this flattens is dropped.
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

from fem_offline.labelmap.io import OUTSIDE, LabelImage, read_label_map
from fem_offline.labelmap.quality import signed_volumes
from fem_offline.scene import Guide, LabelMap, MeshSize, Scene

log = logging.getLogger(__name__)

TETGEN_RADIUS_EDGE = 1.5  # TetGen -q: the largest circumradius / shortest edge of a tet it refines to
REGION_PURITY = 0.9  # a region TetGen closes off must be at least this fraction one tissue
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
    """The tissue of each voxel from the scene's label table;
    ValueError naming the field for an unknown or empty label."""
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


def _cgal(tissues: VoxelTissues, *, size: MeshSize, guide: Guide,
          facet_distance_voxels: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CGAL's labelled-image mesher (pygalmesh): points (n, 3) in voxel index coordinates, tets (m, 4), tissue (m,).

    Cell sizes are per label, so the guide's fine ball is a label of its own (the tissue's voxels
    within 1.5 patch radii of the tip), merged back into its tissue after meshing.
    """
    import pygalmesh

    image, n = tissues.image, len(tissues.names)
    sub = tissues.index.astype(np.int16) + 1  # CGAL: 0 = outside, tissue t = t + 1
    shape = np.array(sub.shape)
    centres = image.to_physical(np.stack(np.meshgrid(*(np.arange(k) for k in shape), indexing="ij"), -1).reshape(-1, 3))
    near_tip = (np.linalg.norm(centres - np.asarray(guide.tip_mm), axis=1)
                < 1.5 * guide.patch_radius_mm).reshape(sub.shape)
    near_tip &= sub > 0
    sub[near_tip] += n  # tissue t near the tip = t + 1 + n
    sizes = {t + 1: (size.prostate_mm if name == "prostate" else size.max_mm) for t, name in enumerate(tissues.names)}
    sizes.update({t + 1 + n: size.guide_mm for t in range(n)})
    spacing = tuple(float(s) for s in image.spacing_mm)
    with _quiet_native_output():  # CGAL prints its progress whatever `verbose` says
        mesh = pygalmesh.generate_from_array(
            np.pad(sub, 1).astype(np.uint8), spacing, max_cell_circumradius=sizes,
            max_facet_distance=facet_distance_voxels * float(min(spacing)),
            max_radius_surface_delaunay_ball=size.prostate_mm,
            min_facet_angle=25.0, max_circumradius_edge_ratio=3.0, verbose=False, seed=0)
    tets = mesh.get_cells_type("tetra").astype(np.int64)
    label = mesh.get_cell_data("medit:ref", "tetra").astype(np.int64)
    points = mesh.points / np.asarray(spacing) - 1.0  # CGAL puts voxel i's centre at i * spacing; one pad layer
    return points, tets, (label - 1) % n


def _interfaces(tissues: VoxelTissues, guide: Guide):
    """The smoothed, decimated interfaces (surface.Surface, scaled index coordinates); the prostate's
    decimated least, the lumen around the guide tip (1.5 patch radii, as CGAL's guide ball) not at all."""
    from fem_offline.labelmap.surface import interface_surface

    spacing = tissues.image.spacing_mm
    fine = tissues.names.index("prostate") if "prostate" in tissues.names else None
    tip = tissues.image.to_index(np.asarray(guide.tip_mm, dtype=np.float64)[None])[0] * spacing
    return interface_surface(tissues.index, spacing, fine_label=fine, keep_ball=(tip, 1.5 * guide.patch_radius_mm))


def _tetgen(tissues: VoxelTissues, *, size: MeshSize, guide: Guide) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """TetGen (constrained Delaunay, -pYq) on the smoothed interfaces: points (n, 3) in voxel index coordinates,
    tets (m, 4), tissue (m,).

    The interface triangles are kept as they are (-Y), so the tissues are bonded along them; each
    closed region TetGen finds (-A) takes the tissue most of its volume's voxels hold. The size is
    set by the surface (about a voxel where it curves, decimated where flat) and grows inward
    by the radius-edge bound; `size` and `guide` are not used (TetGen's background-mesh sizing
    crashed on these inputs).
    """
    import tetgen

    surface = _interfaces(tissues, guide)
    spacing = tissues.image.spacing_mm
    points, tets, region, _ = tetgen.TetGen(surface.vertices, surface.triangles.astype(np.int32)).tetrahedralize(
        switches=f"pYq{TETGEN_RADIUS_EDGE}AQ")
    points, tets = points / spacing, np.asarray(tets, dtype=np.int64)  # back to voxel index coordinates
    return points, tets, _tissue_by_region(points, tets, np.asarray(region).ravel(), tissues)


def _tissue_by_region(points: np.ndarray, tets: np.ndarray, region: np.ndarray, tissues: VoxelTissues) -> np.ndarray:
    """Tissue (m,) of each tet: the tissue of most of its region's volume by the voxel at each tet's centroid;
    OUTSIDE regions are dropped later."""
    ids, region = np.unique(region, return_inverse=True)
    shape = np.array(tissues.index.shape)
    voxel = np.clip(np.rint(points[tets].mean(axis=1)).astype(int), 0, shape - 1)
    label = tissues.index[tuple(voxel.T)] + 1  # 0 = OUTSIDE
    votes = np.zeros((len(ids), len(tissues.names) + 1))
    np.add.at(votes, (region, label), np.abs(signed_volumes(points, tets)))
    purity = votes.max(axis=1) / votes.sum(axis=1)
    if purity.min() < REGION_PURITY:
        raise ValueError(f"label_map: a meshed region is only {purity.min():.0%} one tissue; its interfaces leak")
    return (votes.argmax(axis=1) - 1)[region]


def _ftetwild(tissues: VoxelTissues, *, size: MeshSize, guide: Guide) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """fTetWild on the smoothed interfaces, sized like the phantom: points (n, 3) in voxel index coordinates,
    tets (m, 4), tissue (m,) by centroid voxel."""
    import pytetwild

    image = tissues.image
    spacing = image.spacing_mm
    surface = _interfaces(tissues, guide)
    vertices_mm = image.to_physical(surface.vertices / spacing)
    size_at = lambda p: size_mm(p, tissues=tissues, size=size, guide=guide)  # noqa: E731
    lo, hi = vertices_mm.min(axis=0), vertices_mm.max(axis=0)
    bg_points, bg_tets = box_grid(lo - 1.0, hi + 1.0, 2.0)
    diagonal = float(np.linalg.norm(hi - lo))
    points, tets = pytetwild.tetrahedralize(
        vertices_mm, surface.triangles.astype(np.int32), edge_length_abs=float(size_at(bg_points).max()),
        epsilon=ENVELOPE_VOXELS * float(spacing.min()) / diagonal, disable_filtering=True, num_threads=1, quiet=True,
        bg_vertices=bg_points, bg_tets=bg_tets.astype(np.int32), bg_values=size_at(bg_points))
    points = image.to_index(np.asarray(points, dtype=np.float64))
    tets = np.asarray(tets, dtype=np.int64)
    shape = np.array(tissues.index.shape)
    centroid = points[tets].mean(axis=1)
    voxel = np.clip(np.rint(centroid).astype(int), 0, shape - 1)
    tissue = tissues.index[tuple(voxel.T)].astype(np.int64)
    # without its filtering, fTetWild fills its own bounding box, which is larger than the image's:
    # a tet whose centroid is outside the image is OUTSIDE, not the tissue of the nearest edge voxel
    tissue[((centroid < -0.5) | (centroid > shape - 0.5)).any(axis=1)] = OUTSIDE
    return points, tets, tissue


def snap_to_box(points_index: np.ndarray, tets: np.ndarray, shape, tol_voxels: float = 0.25) -> np.ndarray:
    """Put the mesh's boundary nodes within tol_voxels of the image box (voxel index coordinates) exactly on its faces.

    Interior nodes stay: one near the box (a TetGen Steiner point) would flatten its tets.
    """
    from contracts.tet10 import FACES

    faces = np.sort(tets[:, FACES].reshape(-1, 3), axis=1)
    unique, count = np.unique(faces, axis=0, return_counts=True)
    boundary = np.zeros(len(points_index), dtype=bool)
    boundary[unique[count == 1]] = True
    lo, hi = np.full(3, -0.5), np.asarray(shape, dtype=np.float64) - 0.5
    p = points_index.copy()
    p = np.where(boundary[:, None] & (np.abs(p - lo) < tol_voxels), lo, p)
    return np.where(boundary[:, None] & (np.abs(p - hi) < tol_voxels), hi, p)


def flat_on_box(points_index: np.ndarray, tets: np.ndarray, shape) -> np.ndarray:
    """Mask (m,) of the tets whose four corners lie in one face of the image box: no volume once snapped.

    A mesher that approximates the box's faces within a tolerance leaves thin tets on them, all four
    corners within a quarter voxel of the face (CGAL does, rarely: CHANGELOG, issue 50). Snapping puts
    them in the plane; dropping them leaves their two inner faces as the box face, which they now are.
    """
    lo, hi = np.full(3, -0.5), np.asarray(shape, dtype=np.float64) - 0.5
    corners = points_index[tets[:, :4]]  # (m, 4, 3)
    return ((corners == lo).all(axis=1) | (corners == hi).all(axis=1)).any(axis=1)


MESHERS = {"cgal": _cgal, "tetgen": _tetgen, "ftetwild": _ftetwild}
PACKAGE_HINT = {"cgal": "`make labelmesh` builds pygalmesh against CGAL; or label_map.mesher = \"tetgen\"",
                "tetgen": "the offline extra installs tetgen and vtk", "ftetwild": "the ftetwild extra"}


def mesh_label_map(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[str, ...]]:
    """Mesh the scene's label map: nodes (n, 3) RAS mm, corner tets (m, 4), tissue (m,), tissue names."""
    spec = scene.label_map
    image = read_label_map(spec.path)
    tissues = voxel_tissues(image, spec)
    t0 = time.perf_counter()
    try:
        options = {"facet_distance_voxels": spec.facet_distance_voxels} if spec.mesher == "cgal" else {}
        points, tets, tissue = MESHERS[spec.mesher](tissues, size=scene.mesh, guide=scene.guide, **options)
    except ModuleNotFoundError as exc:
        raise ValueError(f"label_map.mesher: {spec.mesher!r} needs the package {exc.name!r} "
                         f"({PACKAGE_HINT.get(spec.mesher, 'pip install it')})") from None
    snapped = snap_to_box(points, tets, image.labels.shape)
    keep = (tissue >= 0) & ~flat_on_box(snapped, tets, image.labels.shape)  # OUTSIDE: a closed-off lumen or cavity
    flipped = np.sign(signed_volumes(snapped, tets[keep])) != np.sign(signed_volumes(points, tets[keep]))
    if flipped.any():
        raise ValueError(f"label_map: putting the nodes on the image box would flatten or invert {flipped.sum()} tets")
    points, tets, tissue = image.to_physical(snapped), tets[keep], tissue[keep]
    log.info("label map %s: %d tets, %d vertices by %s in %.1f s", spec.path.name, len(tets), len(points),
             spec.mesher, time.perf_counter() - t0)
    return points, tets, tissue, tissues.names
