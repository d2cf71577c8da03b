"""Find the tet holding each point of a straight-sided tet10 mesh and interpolate P2 fields there.

Public: `PointLocator` (tet and barycentric coordinates of each point), `interpolate` (values at
located points from their tet's 10 nodal values) and `interpolation_matrix` (the sparse P2 transfer
from a mesh's nodes to points, for mesh-to-mesh transfer). numpy and scipy only; scipy is imported
inside the functions, so `import contracts` stays light.
"""

from __future__ import annotations

import numpy as np

from .tet10 import p2_weights


class PointLocator:
    """Find the tet containing each point (tets are straight-sided: barycentric test on the corners)."""

    def __init__(self, nodes: np.ndarray, tets: np.ndarray, *, candidates: int = 16):
        from scipy.spatial import cKDTree

        corners = nodes[tets[:, :4]]  # (m, 4, 3)
        self._origin = corners[:, 3]
        t = (corners[:, :3] - corners[:, 3:4]).transpose(0, 2, 1)  # (m, 3, 3) columns v0-v3, v1-v3, v2-v3
        self._inverse = np.linalg.inv(t)
        self._tree = cKDTree(corners.mean(axis=1))
        self._k = min(candidates, len(tets))
        self._lo, self._hi = nodes.min(axis=0), nodes.max(axis=0)

    def barycentric(self, points: np.ndarray, tet: np.ndarray) -> np.ndarray:
        """Barycentric coordinates (..., 4) of `points` (..., 3) in tets `tet` (...)."""
        lam = np.einsum("...ij,...j->...i", self._inverse[tet], points - self._origin[tet])
        return np.concatenate([lam, 1.0 - lam.sum(axis=-1, keepdims=True)], axis=-1)

    def candidates(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(point index, tet index) of every barycentric test `locate` makes."""
        points = np.asarray(points, dtype=np.float64)
        _, cand = self._tree.query(points, k=self._k)
        cand = cand.reshape(len(points), -1)
        inside = self.barycentric(points[:, None, :], cand).min(axis=-1) >= -1e-9
        # Slivers can put the containing tet outside the nearest centroids: the rest are tried exhaustively.
        in_box = np.all((points >= self._lo - 1e-9) & (points <= self._hi + 1e-9), axis=1)
        rest = np.flatnonzero(~inside.any(axis=1) & in_box)
        m = len(self._origin)
        point = np.concatenate([np.repeat(np.arange(len(points)), cand.shape[1]), np.repeat(rest, m)])
        return point, np.concatenate([cand.ravel(), np.tile(np.arange(m), len(rest))])

    def locate(self, points: np.ndarray, *, tol: float = 1e-9, nearest: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Tet index (k,) and barycentric coordinates (k, 4) of each point; tet -1 where outside.

        nearest: give an outside point the candidate tet it is least far outside of, and the
        barycentric coordinates of its projection onto that tet's nearest face (clipped into the
        face where the projection falls beyond an edge), for mesh-to-mesh transfer across curved
        boundaries.
        """
        points = np.asarray(points, dtype=np.float64)
        point, tet_of = self.candidates(points)
        lam = self.barycentric(points[point], tet_of)
        score = _score(lam)
        best = np.full(len(points), -np.inf)
        np.maximum.at(best, point, score)
        win = score == best[point]
        hit, first = np.unique(point[win], return_index=True)
        tet = np.full(len(points), -1)
        bary = np.zeros((len(points), 4))
        tet[hit], bary[hit] = tet_of[win][first], lam[win][first]
        out = best < -tol
        if nearest:
            clip = np.flatnonzero(out & (tet >= 0))
            bary[clip] = self._project(bary[clip], tet[clip])
        else:
            tet[out] = -1
        bary = np.clip(bary, 0.0, None)
        bary[tet >= 0] /= bary[tet >= 0].sum(axis=1, keepdims=True)
        return tet, bary

    def _gradients(self, tet: np.ndarray) -> np.ndarray:
        """(k, 4, 3) gradients of the 4 barycentric coordinates in tets `tet`."""
        g = self._inverse[tet]  # rows: gradients of lambda_0..2
        return np.concatenate([g, -g.sum(axis=1, keepdims=True)], axis=1)

    def _project(self, lam: np.ndarray, tet: np.ndarray) -> np.ndarray:
        """Barycentric coordinates of each point moved normally onto the plane of its most violated face."""
        g = self._gradients(tet)
        i = lam.argmin(axis=1)
        gi = g[np.arange(len(lam)), i]  # (k, 3)
        along = np.einsum("kvd,kd->kv", g, gi) / np.einsum("kd,kd->k", gi, gi)[:, None]
        return lam - lam[np.arange(len(lam)), i][:, None] * along


def _score(lam: np.ndarray) -> np.ndarray:
    """How far inside each (point, tet) pair is: the smallest barycentric coordinate when inside, minus
    the root sum of squares of the negative ones when outside (so among tets a point is outside of,
    the one it is straight across a face from scores best)."""
    neg = np.minimum(lam, 0.0)
    return np.where(lam.min(axis=1) >= 0, lam.min(axis=1), -np.sqrt((neg * neg).sum(axis=1)))


def interpolate(values: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Values (k, ...) at points from their tet's 10 nodal values (k, 10, ...) and barycentrics (k, 4)."""
    return np.einsum("kn,kn...->k...", p2_weights(bary), values)


def interpolation_matrix(nodes: np.ndarray, tets: np.ndarray, points: np.ndarray, *,
                         nearest: bool = False):
    """P2 interpolation weights (k, n_nodes) as scipy.sparse CSR: `W @ field` is the field at `points`.

    A point outside the mesh raises ValueError, unless nearest=True clips it to the tet it is least
    outside of.
    """
    import scipy.sparse as sp

    if tets.shape[1] != 10:
        raise ValueError(f"tets must be tet10 (m, 10), got {tets.shape}")
    tet, bary = PointLocator(nodes, tets).locate(points, nearest=nearest)
    outside = np.flatnonzero(tet < 0)
    if len(outside):
        raise ValueError(f"{len(outside)} of {len(points)} points are outside the mesh (first: points[{outside[0]}] = "
                         f"{np.asarray(points)[outside[0]].tolist()}); pass nearest=True to clip them to the nearest tet")
    rows = np.repeat(np.arange(len(points)), 10)
    return sp.csr_matrix((p2_weights(bary).ravel(), (rows, tets[tet].ravel())), shape=(len(points), len(nodes)))
