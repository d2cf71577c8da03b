"""Find the tet holding each point of a straight-sided tet10 mesh and interpolate P2 fields there.

Public: `PointLocator` (tet and barycentric coordinates of each point), `interpolate` (values at
located points from their tet's 10 nodal values) and `interpolation_matrix` (the sparse P2 transfer
from a mesh's nodes to points, for mesh-to-mesh transfer). numpy and scipy only; scipy is imported
inside the functions, so `import contracts` stays light.
"""

from __future__ import annotations

import numpy as np

from .tet10 import p2_weights


# A point within this distance outside the mesh still counts as inside: float32 rounding of
# coordinates up to 1000 mm moves a point by at most 6e-5 mm, so a node sent as float32 is found.
TOL_MM = 1e-4
# Grid cells per largest tet bounding box of a size class, along each axis: finer cells list fewer
# tets a point need not test, at the cost of more (cell, tet) entries: about 21 per tet of the
# default mesh at 3 (38 at 4), at most (3 + 1)^3.
_CELLS = 3


class PointLocator:
    """Find the tet containing each point: a hashed grid per tet size class, then a barycentric test.

    Tets are sorted into size classes (bounding-box extent within a factor 2). Each class has a
    uniform grid whose cells, a third of the class's largest extent, list the tets whose bounding
    box (widened by tol_mm) overlaps them; only occupied cells are stored, sorted by key. A point
    looks up its cell in each class (a binary search), keeps the listed tets whose box holds it and
    tests those barycentrically. That is O(classes * log cells) plus a candidate count set by the
    mesh's local shape, not its size; slivers are found because boxes, not centroids, are listed.
    Tets are straight-sided (the tet10 corners define them).
    """

    def __init__(self, nodes: np.ndarray, tets: np.ndarray, *, tol_mm: float = TOL_MM):
        corners = np.asarray(nodes, dtype=np.float64)[tets[:, :4]]  # (m, 4, 3)
        self.tol_mm = tol_mm
        self._origin = corners[:, 3]
        t = (corners[:, :3] - corners[:, 3:4]).transpose(0, 2, 1)  # (m, 3, 3) columns v0-v3, v1-v3, v2-v3
        self._inverse = np.linalg.inv(t)
        self._lo, self._hi = corners.min(axis=1) - tol_mm, corners.max(axis=1) + tol_mm  # (m, 3) widened boxes
        self._grid_origin = self._lo.min(axis=0)
        # (3, m) float32 copies for the box filter: rounding (< 1e-5 mm below 100 mm) is far inside tol_mm
        self._lo_axes, self._hi_axes = (np.ascontiguousarray(b.T, dtype=np.float32) for b in (self._lo, self._hi))
        extent = (self._hi - self._lo).max(axis=1)
        size_class = np.floor(np.log2(extent / extent.min())).astype(int)
        self._grids = [self._grid(np.flatnonzero(size_class == c)) for c in np.unique(size_class)]
        self._centroids = corners.mean(axis=1)
        # (4, m): each corner's altitude above its opposite face, mm
        self._heights_t = np.ascontiguousarray(1.0 / np.linalg.norm(self._gradients(np.arange(len(tets))), axis=-1).T)

    def _grid(self, ids: np.ndarray) -> tuple:
        """(cell size, grid shape, sorted occupied cell keys, start of each cell's list, tet ids) of one class."""
        h = (self._hi[ids] - self._lo[ids]).max() / _CELLS
        a = np.floor((self._lo[ids] - self._grid_origin) / h).astype(np.int64)  # first cell of each box
        b = np.floor((self._hi[ids] - self._grid_origin) / h).astype(np.int64)  # last cell
        shape = b.max(axis=0) + 1
        keys, owner = [], []
        for offset in np.ndindex(*(b - a + 1).max(axis=0)):
            inside = np.all(a + offset <= b, axis=1)
            keys.append(self._key(a[inside] + offset, shape))
            owner.append(ids[inside])
        keys, owner = np.concatenate(keys), np.concatenate(owner).astype(np.int32)
        order = np.argsort(keys)
        keys, owner = keys[order], owner[order]
        start = np.flatnonzero(np.diff(keys, prepend=-1))  # where each occupied cell's list begins
        return h, shape, keys[start], np.append(start, len(keys)), owner

    @staticmethod
    def _key(cell: np.ndarray, shape: np.ndarray) -> np.ndarray:
        return (cell[:, 0] * shape[1] + cell[:, 1]) * shape[2] + cell[:, 2]

    def barycentric(self, points: np.ndarray, tet: np.ndarray) -> np.ndarray:
        """Barycentric coordinates (..., 4) of `points` (..., 3) in tets `tet` (...)."""
        lam = np.einsum("...ij,...j->...i", self._inverse[tet], points - self._origin[tet])
        return np.concatenate([lam, 1.0 - lam.sum(axis=-1, keepdims=True)], axis=-1)

    def _barycentric_t(self, points: np.ndarray, tet: np.ndarray) -> np.ndarray:
        """barycentric() for (k, 3) points, laid out (4, k): reductions over 4 rows run far faster."""
        lam = np.empty((4, len(tet)))
        np.einsum("kij,kj->ik", self._inverse[tet], points - self._origin[tet], out=lam[:3])
        np.subtract(1.0, lam[:3].sum(axis=0), out=lam[3])
        return lam

    def candidates(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(point index, tet index) of every barycentric test `locate` makes: the tets whose widened
        bounding box holds the point."""
        axes = np.ascontiguousarray(np.asarray(points, dtype=np.float64).T)  # (3, k): one gather per axis below
        axes32 = axes.astype(np.float32)
        found_point, found_tet = [], []
        for h, shape, cells, start, owner in self._grids:
            cell = np.floor((axes - self._grid_origin[:, None]) / h).astype(np.int64)  # (3, k)
            key = (cell[0] * shape[1] + cell[1]) * shape[2] + cell[2]
            at = np.minimum(np.searchsorted(cells, key), len(cells) - 1)
            valid = (cells[at] == key) & (cell >= 0).all(axis=0) & (cell < shape[:, None]).all(axis=0)
            hit = np.flatnonzero(valid)
            first, count = start[at[hit]], start[at[hit] + 1] - start[at[hit]]
            # the tets listed in each hit cell, flattened: (point, tet) pairs
            found_point.append(np.repeat(hit, count))
            found_tet.append(owner[np.repeat(first - np.cumsum(count) + count, count) + np.arange(count.sum())])
        point, tet = np.concatenate(found_point), np.concatenate(found_tet)
        for axis in range(3):  # keep the pairs whose box holds the point, one axis at a time
            p = axes32[axis][point]
            keep = (p >= self._lo_axes[axis][tet]) & (p <= self._hi_axes[axis][tet])
            point, tet = point[keep], tet[keep]
        return point, tet

    def locate(self, points: np.ndarray, *, tol_mm: float | None = None,
               nearest: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Tet index (k,) and barycentric coordinates (k, 4) of each point; tet -1 where outside.

        A point within tol_mm (at most the locator's own tol_mm) outside a face is inside. Of the
        tets holding a point, the one it is deepest inside is given. nearest: give an outside point
        the tet it is least far outside of and the barycentric coordinates of its projection onto
        that tet's nearest face (clipped into the face where it falls beyond an edge), for
        mesh-to-mesh transfer across curved boundaries.
        """
        tol_mm = self.tol_mm if tol_mm is None else tol_mm
        if tol_mm > self.tol_mm:
            raise ValueError(f"tol_mm={tol_mm} is over the {self.tol_mm} mm this locator was built with")
        points = np.asarray(points, dtype=np.float64)
        tet, bary, depth = self._deepest(points, *self.candidates(points))
        out = depth < -tol_mm
        if nearest and out.any():
            miss = np.flatnonzero(out)
            near = self._near(points[miss])
            tet[miss], bary[miss], _ = self._deepest(points[miss], *near, len(miss))
            bary[miss] = self._project(bary[miss], tet[miss])
        elif not nearest:
            tet[out] = -1
        bary = np.clip(bary, 0.0, None)
        bary[tet >= 0] /= bary[tet >= 0].sum(axis=1, keepdims=True)
        return tet, bary

    def _deepest(self, points: np.ndarray, point: np.ndarray, tet_of: np.ndarray,
                 n: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per point, of the candidate (point, tet) pairs: the tet it is deepest in, its barycentric
        coordinates there and that depth in mm (-inf without candidates)."""
        n = len(points) if n is None else n
        lam = self._barycentric_t(points[point], tet_of)  # (4, pairs)
        score = _depth_mm(lam, self._heights_t[:, tet_of])
        depth = np.full(n, -np.inf)
        np.maximum.at(depth, point, score)
        win = np.flatnonzero(score == depth[point])
        pair = np.full(n, -1)
        pair[point[win]] = win  # one winning pair per point (which one, among exact ties, is immaterial)
        hit = pair >= 0
        tet, bary = np.full(n, -1), np.zeros((n, 4))
        tet[hit], bary[hit] = tet_of[pair[hit]], lam[:, pair[hit]].T
        return tet, bary, depth

    def _near(self, points: np.ndarray, k: int = 16) -> tuple[np.ndarray, np.ndarray]:
        """(point index, tet index) pairs of the k tets with the nearest centroids, for points outside the mesh."""
        from scipy.spatial import cKDTree

        k = min(k, len(self._centroids))
        _, tet = cKDTree(self._centroids).query(points, k=k)
        return np.repeat(np.arange(len(points)), k), tet.reshape(-1)

    def _gradients(self, tet: np.ndarray) -> np.ndarray:
        """(k, 4, 3) gradients of the 4 barycentric coordinates in tets `tet`, 1/mm."""
        g = self._inverse[tet]  # rows: gradients of lambda_0..2
        return np.concatenate([g, -g.sum(axis=1, keepdims=True)], axis=1)

    def _project(self, lam: np.ndarray, tet: np.ndarray) -> np.ndarray:
        """Barycentric coordinates of each point moved normally onto the plane of its most violated face."""
        g = self._gradients(tet)
        i = lam.argmin(axis=1)
        gi = g[np.arange(len(lam)), i]  # (k, 3)
        along = np.einsum("kvd,kd->kv", g, gi) / np.einsum("kd,kd->k", gi, gi)[:, None]
        return lam - lam[np.arange(len(lam)), i][:, None] * along


def _depth_mm(lam: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """How far inside its tet each point is, mm: the distance to the nearest face plane when inside;
    minus the root sum of squares of its distances beyond the face planes it is outside of (the
    exact distance when it is straight across one face). lam, heights: (4, k), heights each
    corner's altitude."""
    signed = lam * heights  # (4, k) signed distance to each face plane
    nearest = signed.min(axis=0)
    beyond = np.minimum(signed, 0.0)
    return np.where(nearest >= 0, nearest, -np.sqrt((beyond * beyond).sum(axis=0)))


def interpolate(values: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Values (k, ...) at points from their tet's 10 nodal values (k, 10, ...) and barycentrics (k, 4)."""
    return np.einsum("kn,kn...->k...", p2_weights(bary), values)


def interpolation_matrix(nodes: np.ndarray, tets: np.ndarray, points: np.ndarray, *, tol_mm: float = TOL_MM,
                         nearest: bool = False):
    """P2 interpolation weights (k, n_nodes) as scipy.sparse CSR: `W @ field` is the field at `points`.

    A point outside the mesh raises ValueError, unless nearest=True clips it to the tet it is least
    outside of.
    """
    import scipy.sparse as sp

    if tets.shape[1] != 10:
        raise ValueError(f"tets must be tet10 (m, 10), got {tets.shape}")
    tet, bary = PointLocator(nodes, tets, tol_mm=tol_mm).locate(points, nearest=nearest)
    outside = np.flatnonzero(tet < 0)
    if len(outside):
        raise ValueError(f"{len(outside)} of {len(points)} points are outside the mesh (first: points[{outside[0]}] = "
                         f"{np.asarray(points)[outside[0]].tolist()}); "
                         "pass nearest=True to clip them to the nearest tet")
    rows = np.repeat(np.arange(len(points)), 10)
    return sp.csr_matrix((p2_weights(bary).ravel(), (rows, tets[tet].ravel())), shape=(len(points), len(nodes)))
