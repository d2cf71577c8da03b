"""The tissue interfaces of a label map as one conforming triangle surface: surface nets, smoothed, decimated.

    tissue per voxel --(surface nets)--> a quad on every voxel face between two labels, its corners
    on the voxel corners --(constrained Taubin smoothing)--> vertices moved at most
    `max_move_voxels` off the staircase --(decimation per interface patch, patch borders kept)-->
    few triangles where the surface is flat --(check)--> no two triangles cross

Labels here: 0 = outside (the rectal lumen), t + 1 = tissue t, PAD = the layer around the image.
The image's box is an interface too (tissue | PAD); its vertices stay on its planes, so the box stays
a box. Each interface patch (one label pair, and one box plane for the box) is decimated on its own
with its border vertices kept, so neighbouring patches still share their border edges: the surface
stays conforming. A vertex where three or more labels meet (a junction curve, e.g. the prostate's
contact line with the rectal wall and adipose) is smoothed along its curve only.
Units: voxel index coordinates scaled by the spacing (mm, axis-aligned); the caller applies the direction.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from fem_offline.labelmap.self_intersection import crossing_triangles

log = logging.getLogger(__name__)

MAX_MOVE_VOXELS = 0.5  # how far smoothing may move a vertex off its voxel corner
SMOOTHING_ITERATIONS = 20  # Taubin lambda|mu pairs
TAUBIN_LAMBDA, TAUBIN_MU = 0.5, -0.53  # Taubin (1995): the mu step undoes the shrinkage of the lambda step


@dataclass(frozen=True)
class Surface:
    vertices: np.ndarray  # (n, 3) scaled voxel index coordinates, mm along the index axes
    triangles: np.ndarray  # (m, 3)
    pairs: np.ndarray  # (m, 2) the two labels each triangle separates, sorted (0 outside, t + 1 tissue, pad)
    pad: int  # label of the layer around the image


def _quads(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Corner grid ids (q, 4) of every voxel face between two different labels (one of them tissue)
    and the pair (q, 2)."""
    corner_shape = np.array(labels.shape) + 1
    quads, pairs = [], []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        lo = labels[tuple(slice(0, -1) if k == a else slice(None) for k in range(3))]
        hi = labels[tuple(slice(1, None) if k == a else slice(None) for k in range(3))]
        p = np.argwhere(lo != hi)  # voxel p and p + e_a differ
        pair = np.sort(np.stack([lo[tuple(p.T)], hi[tuple(p.T)]], axis=1), axis=1)
        q0 = p.copy()
        q0[:, a] += 1  # the face lies on corner plane p_a + 1
        eb, ec = np.eye(3, dtype=int)[b], np.eye(3, dtype=int)[c]
        ring = np.stack([q0, q0 + eb, q0 + eb + ec, q0 + ec], axis=1)  # (q, 4, 3) around the face
        quads.append(np.ravel_multi_index(tuple(ring.reshape(-1, 3).T), corner_shape).reshape(-1, 4))
        pairs.append(pair)
    return np.concatenate(quads), np.concatenate(pairs)


def _corner_labels(labels: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """How many distinct labels (k,) the 2 x 2 x 2 voxels around each corner (k, 3) hold."""
    around = np.stack([labels[tuple((corners - np.array(o)).T)] for o in np.ndindex(2, 2, 2)], axis=1)  # (k, 8)
    s = np.sort(around, axis=1)
    return 1 + (np.diff(s, axis=1) != 0).sum(axis=1)


def _neighbours(quads: np.ndarray, n: int, junction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smoothing stencil as (vertex, neighbour) pairs: quad edges; a junction vertex sees only junction
    vertices, and only when it has exactly two (a curve), else it is fixed."""
    import scipy.sparse as sp

    e = np.concatenate([quads[:, [k, (k + 1) % 4]] for k in range(4)])
    e = np.unique(np.sort(e, axis=1), axis=0)
    both = np.concatenate([e, e[:, ::-1]])
    keep = ~junction[both[:, 0]] | junction[both[:, 1]]
    both = both[keep]
    count = np.bincount(both[:, 0], minlength=n)
    fixed = junction & (count != 2)
    both = both[~fixed[both[:, 0]]]
    w = sp.csr_matrix((np.ones(len(both)), (both[:, 0], both[:, 1])), shape=(n, n))
    deg = np.asarray(w.sum(axis=1)).ravel()
    return sp.diags(np.where(deg > 0, 1.0 / np.maximum(deg, 1), 0.0)) @ w, deg > 0


def smooth(v0: np.ndarray, quads: np.ndarray, *, junction: np.ndarray, box_axes: np.ndarray, max_move: float,
           iterations: int = SMOOTHING_ITERATIONS) -> np.ndarray:
    """Taubin smoothing (lambda|mu) of quad-mesh vertices (n, 3), each kept within max_move of v0 and
    on the box planes it starts on (box_axes (n, 3) bool: that coordinate is fixed)."""
    mean, moves = _neighbours(quads, len(v0), junction)
    v = v0.copy()
    for _ in range(iterations):
        for factor in (TAUBIN_LAMBDA, TAUBIN_MU):
            v = v + factor * moves[:, None] * (mean @ v - v)
            v = np.where(box_axes, v0, v)
            d = v - v0
            r = np.linalg.norm(d, axis=1, keepdims=True)
            v = v0 + d * np.minimum(1.0, max_move / np.maximum(r, 1e-300))
    return v


def surface_nets(index: np.ndarray, spacing_mm, *, max_move_voxels: float = MAX_MOVE_VOXELS,
                 iterations: int = SMOOTHING_ITERATIONS) -> tuple[Surface, np.ndarray]:
    """Smoothed interface surface of a tissue-index volume (OUTSIDE = -1) and the unsmoothed vertices (n, 3)."""
    spacing = np.asarray(spacing_mm, dtype=np.float64)
    pad = int(index.max()) + 2
    labels = np.pad(index.astype(np.int16) + 1, 1, constant_values=pad)
    quads, pairs = _quads(labels)
    tissue = ((pairs >= 1) & (pairs < pad)).any(axis=1)
    quads, pairs = quads[tissue], pairs[tissue]  # outside | pad faces are not an interface
    used, inverse = np.unique(quads, return_inverse=True)
    quads = inverse.reshape(-1, 4)
    corners = np.stack(np.unravel_index(used, np.array(labels.shape) + 1), axis=1)
    v0 = (corners - 1.5) * spacing  # corner c sits at padded voxel index c - 0.5, image index c - 1.5
    box_axes = (corners == 1) | (corners == np.array(labels.shape) - 1)
    junction = _corner_labels(labels, corners) >= 3
    v = smooth(v0, quads, junction=junction, box_axes=box_axes, max_move=max_move_voxels * float(spacing.min()),
               iterations=iterations)
    # split each quad along its shorter diagonal
    d02 = np.linalg.norm(v[quads[:, 0]] - v[quads[:, 2]], axis=1)
    d13 = np.linalg.norm(v[quads[:, 1]] - v[quads[:, 3]], axis=1)
    a = np.where((d02 <= d13)[:, None], quads[:, [0, 1, 2]], quads[:, [1, 2, 3]])
    b = np.where((d02 <= d13)[:, None], quads[:, [0, 2, 3]], quads[:, [1, 3, 0]])
    triangles = np.concatenate([a, b])
    return Surface(v, triangles, np.concatenate([pairs, pairs]).astype(np.int64), pad), v0


def patches(surface: Surface, unsmoothed: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray) -> np.ndarray:
    """Patch id (m,) of each triangle: its label pair, and for the box (tissue | pad) the box plane it lies in."""
    t = surface.triangles
    pair_id = surface.pairs[:, 0] * (surface.pad + 1) + surface.pairs[:, 1]
    plane = np.full(len(t), -1)
    for axis in range(3):
        for side, bound in enumerate((box_lo, box_hi)):
            on = np.isclose(unsmoothed[t, axis], bound[axis]).all(axis=1)
            plane[on & (surface.pairs[:, 1] == surface.pad)] = 2 * axis + side
    return pair_id * 7 + plane + 1


def _decimate_vtk(points: np.ndarray, triangles: np.ndarray, error_mm: float) -> np.ndarray:
    """vtkDecimatePro on one patch, border vertices kept: the triangles (k, 3) in the input's vertex ids."""
    # vtkmodules, not `vtk`: the filters alone, without the rendering modules and their GL libraries
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray, vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData
    from vtkmodules.vtkFiltersCore import vtkDecimatePro

    poly = vtkPolyData()
    pts = vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(points), deep=True))
    poly.SetPoints(pts)
    cells = vtkCellArray()
    cells.SetData(3, numpy_to_vtkIdTypeArray(np.ascontiguousarray(triangles, dtype=np.int64).ravel(), deep=True))
    poly.SetPolys(cells)
    ids = numpy_to_vtkIdTypeArray(np.arange(len(points), dtype=np.int64), deep=True)
    ids.SetName("id")
    poly.GetPointData().AddArray(ids)
    d = vtkDecimatePro()
    d.SetInputData(poly)
    d.SetTargetReduction(0.999)
    d.PreserveTopologyOn()
    d.BoundaryVertexDeletionOff()  # the patch border is shared with the neighbouring patches
    d.SplittingOff()
    d.SetErrorIsAbsolute(1)
    d.SetAbsoluteError(error_mm)
    d.AccumulateErrorOn()  # the error bound holds against the smoothed surface, not only the last step
    d.Update()
    out = d.GetOutput()
    kept = vtk_to_numpy(out.GetPointData().GetArray("id"))
    return kept[vtk_to_numpy(out.GetPolys().GetConnectivityArray()).reshape(-1, 3)]


def decimate(surface: Surface, patch: np.ndarray, error_mm: dict[int, float]) -> tuple[np.ndarray, np.ndarray]:
    """Triangles (k, 3) after decimating each patch to within error_mm[patch] of the smoothed surface,
    and their patch (k,)."""
    out, owner = [], []
    for p in np.unique(patch):
        tri = surface.triangles[patch == p]
        if error_mm.get(int(p), 0.0) > 0:
            used, local = np.unique(tri, return_inverse=True)
            tri = used[_decimate_vtk(surface.vertices[used], local.reshape(-1, 3), error_mm[int(p)])]
        out.append(tri)
        owner.append(np.full(len(tri), p))
    return np.concatenate(out), np.concatenate(owner)


DECIMATION_VOXELS = {"prostate": 0.25, "other": 0.5}  # how far decimation may stray from the smoothed surface
_ROUNDS = 8  # rounds of "keep the smoothed triangles where the decimated ones cross" before giving up


def _border_triangles(triangles: np.ndarray, patch: np.ndarray, n_vertices: int) -> np.ndarray:
    """Mask (m,) of the triangles with a vertex on a patch border (a vertex of triangles of two patches)."""
    lowest, highest = np.full(n_vertices, patch.max() + 1), np.full(n_vertices, -1)
    for k in range(3):
        np.minimum.at(lowest, triangles[:, k], patch)
        np.maximum.at(highest, triangles[:, k], patch)
    return (lowest != highest)[triangles].any(axis=1)


def interface_surface(index: np.ndarray, spacing_mm, *, fine_label: int | None = None,
                      keep_ball: tuple[np.ndarray, float] | None = None) -> Surface:
    """Smoothed, decimated, crossing-free interface surface of a tissue-index volume.

    Patches touching `fine_label` (a tissue index, e.g. the prostate) are decimated to within
    DECIMATION_VOXELS["prostate"] of the smoothed surface, the others DECIMATION_VOXELS["other"].
    Kept as smoothed: the triangles along each patch's border (decimating two patches on their own
    otherwise makes "ears" on the shared border that cross or double the neighbour's triangles),
    those within keep_ball (centre (3,) in these coordinates, radius mm: the guide tip's patch), and,
    where decimated triangles still cross, those within a voxel of the crossing ones' boxes, the rest
    decimated again. ValueError if triangles still cross after _ROUNDS rounds.
    """
    spacing = np.asarray(spacing_mm, dtype=np.float64)
    surface, unsmoothed = surface_nets(index, spacing)
    patch = patches(surface, unsmoothed, -0.5 * spacing, (np.array(index.shape) - 0.5) * spacing)
    voxel = float(spacing.min())
    pair_of = {int(p): surface.pairs[patch == p][0] for p in np.unique(patch)}
    kept = int(patch.max()) + 1  # patch id + kept: that patch's smoothed triangles, not decimated
    error = {p: voxel * DECIMATION_VOXELS["prostate" if fine_label is not None and fine_label + 1 in pair else "other"]
             for p, pair in pair_of.items()}
    centroid = surface.vertices[surface.triangles].mean(axis=1)
    keep = _border_triangles(surface.triangles, patch, len(surface.vertices))
    if keep_ball is not None:
        keep |= np.linalg.norm(centroid - np.asarray(keep_ball[0]), axis=1) < keep_ball[1]
    patch = np.where(keep, patch + kept, patch)
    for _ in range(_ROUNDS):
        triangles, owner = decimate(surface, patch, error)
        triangles = delaunay_flips(surface.vertices, triangles, owner)
        crossing = crossing_triangles(surface.vertices, triangles)
        if not crossing.any() or (owner[crossing] >= kept).all():
            break
        box = surface.vertices[triangles[crossing]]  # (c, 3, 3)
        near = np.zeros(len(patch), dtype=bool)
        for lo, hi in zip(box.min(axis=1) - voxel, box.max(axis=1) + voxel):
            near |= np.all((centroid >= lo) & (centroid <= hi), axis=1)
        log.info("decimated interfaces cross in %d triangles: keeping %d smoothed ones there", crossing.sum(),
                 near.sum())
        patch = np.where(near & (patch < kept), patch + kept, patch)
    if crossing.any():
        raise ValueError(f"label_map: the interface surface still crosses itself in {crossing.sum()} triangles "
                         f"(a feature thinner than the {MAX_MOVE_VOXELS} voxel smoothing allows?)")
    pairs = np.stack([pair_of[int(p) % kept] for p in owner])
    used, inverse = np.unique(triangles, return_inverse=True)
    return Surface(surface.vertices[used], inverse.reshape(-1, 3), pairs, surface.pad)


FLIP_MAX_BEND_DEG = 10.0  # an edge is flipped only between triangles this close to coplanar: the surface barely moves


def _angle_at(p, q, r) -> np.ndarray:
    """Angle (k,) radians at p of triangles pqr (rows)."""
    u, w = q - p, r - p
    cos = np.einsum("ij,ij->i", u, w) / (np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1))
    return np.arccos(np.clip(cos, -1.0, 1.0))


def delaunay_flips(v: np.ndarray, tri: np.ndarray, patch: np.ndarray, *, passes: int = 100) -> np.ndarray:
    """Flip edges inside each patch towards a Delaunay triangulation (opposite angles summing over pi):
    decimation leaves fans of thin triangles, and TetGen (-Y) builds its tets on them as they are.

    Only an edge with exactly two triangles, both of one patch, bent by under FLIP_MAX_BEND_DEG,
    whose quad is convex and whose other diagonal is not an edge yet, is flipped; patch borders never move. Each pass
    flips an independent set.
    """
    tri = tri.copy()
    for _ in range(passes):
        e = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
        owner = np.tile(np.arange(len(tri)), 3)
        key = e[:, 0] * len(v) + e[:, 1]
        order = np.argsort(key, kind="stable")
        key, owner, e = key[order], owner[order], e[order]
        first = np.flatnonzero(np.diff(key, prepend=-1))
        count = np.diff(np.append(first, len(key)))
        two = first[count == 2]
        t1, t2, ab = owner[two], owner[two + 1], e[two]
        same = patch[t1] == patch[t2]
        t1, t2, ab = t1[same], t2[same], ab[same]
        c = tri[t1][(tri[t1] != ab[:, :1]) & (tri[t1] != ab[:, 1:])]
        d = tri[t2][(tri[t2] != ab[:, :1]) & (tri[t2] != ab[:, 1:])]
        pa, pb, pc, pd = v[ab[:, 0]], v[ab[:, 1]], v[c], v[d]
        n1, n2 = np.cross(pb - pa, pc - pa), np.cross(pd - pa, pb - pa)  # both face the same way if the surface does
        n1 /= np.linalg.norm(n1, axis=1, keepdims=True)
        n2 /= np.linalg.norm(n2, axis=1, keepdims=True)
        bend_ok = np.einsum("ij,ij->i", n1, n2) > np.cos(np.radians(FLIP_MAX_BEND_DEG))
        n = n1 + n2
        convex = (np.einsum("ij,ij->i", np.cross(pd - pc, pa - pc), n)
                  * np.einsum("ij,ij->i", np.cross(pd - pc, pb - pc), n)) < 0
        excess = _angle_at(pc, pa, pb) + _angle_at(pd, pa, pb) - np.pi
        new_edge = np.minimum(c, d) * len(v) + np.maximum(c, d)
        fresh = ~np.isin(new_edge, key)  # an edge c-d already there (another patch's) would be doubled
        want = bend_ok & convex & fresh & (excess > 1e-9)
        if not want.any():
            break
        # an independent set: each triangle's most violated edge, taken where it is that of both its triangles
        best = np.full(len(tri), -1.0)
        np.maximum.at(best, t1[want], excess[want])
        np.maximum.at(best, t2[want], excess[want])
        pick = want & (excess == best[t1]) & (excess == best[t2])
        taken = np.concatenate([t1[pick], t2[pick]])
        counts = np.bincount(taken, minlength=len(tri))
        pick[pick] = counts[t1[pick]] + counts[t2[pick]] == 2
        if not pick.any():
            break
        tri[t1[pick]] = np.stack([c[pick], d[pick], ab[pick, 1]], axis=1)
        tri[t2[pick]] = np.stack([d[pick], c[pick], ab[pick, 0]], axis=1)
    return tri
