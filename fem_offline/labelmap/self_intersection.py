"""Which triangles of a triangle soup cross, overlap or duplicate another: what TetGen refuses as a PLC.

TetGen stops (or crashes the process) on a self-intersecting input surface, so labelsurface checks
its decimated interfaces here first. Candidate pairs come from a uniform grid of the triangles'
bounding boxes; each pair is then tested by how many vertices it shares. Float tests with a small
tolerance that errs towards "crossing": a false alarm only keeps a few more smoothed triangles.
"""

from __future__ import annotations

import numpy as np


def _candidate_pairs(v: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Triangle pairs (k, 2), i < j, whose bounding boxes overlap: a uniform grid of the boxes,
    then the overlap test."""
    p = v[tri]  # (m, 3, 3)
    lo, hi = p.min(axis=1), p.max(axis=1)
    h = 2.0 * float(np.median((hi - lo).max(axis=1)))
    origin = lo.min(axis=0)
    a, b = np.floor((lo - origin) / h).astype(np.int64), np.floor((hi - origin) / h).astype(np.int64)
    n = b - a + 1
    count = n.prod(axis=1)
    owner = np.repeat(np.arange(len(tri)), count)
    # rank of the cell within the triangle's box
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    nn = n[owner]
    cell = a[owner] + np.stack([k // (nn[:, 1] * nn[:, 2]), (k // nn[:, 2]) % nn[:, 1], k % nn[:, 2]], axis=1)
    shape = cell.max(axis=0) + 1
    key = (cell[:, 0] * shape[1] + cell[:, 1]) * shape[2] + cell[:, 2]
    order = np.argsort(key, kind="stable")
    key, owner = key[order], owner[order]
    start = np.flatnonzero(np.diff(key, prepend=-1))
    size = np.diff(np.append(start, len(key)))
    pairs = []
    for s in np.unique(size[size > 1]):  # all pairs within the cells holding s triangles
        first = start[size == s]
        i, j = np.triu_indices(s, 1)
        pairs.append(np.stack([owner[first[:, None] + i], owner[first[:, None] + j]], axis=-1).reshape(-1, 2))
    if not pairs:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = np.sort(np.concatenate(pairs), axis=1)
    pairs = np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)
    overlap = np.all((lo[pairs[:, 0]] <= hi[pairs[:, 1]]) & (lo[pairs[:, 1]] <= hi[pairs[:, 0]]), axis=1)
    return pairs[overlap]


def _orient(a, b, c, d) -> np.ndarray:
    """Six times the signed volume of (a, b, c, d), rows."""
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)


def _segment_hits(p, q, a, b, c, tol) -> np.ndarray:
    """Whether segment pq (rows) meets triangle abc other than in its plane (touching counts)."""
    sp, sq = _orient(a, b, c, p), _orient(a, b, c, q)
    crosses = (sp * sq <= 0) & ~((np.abs(sp) <= tol) & (np.abs(sq) <= tol))
    e = np.stack([_orient(p, q, a, b), _orient(p, q, b, c), _orient(p, q, c, a)], axis=1)
    inside = (e >= -tol).all(axis=1) | (e <= tol).all(axis=1)
    return crosses & inside


def _coplanar_overlap(pa, pb, shared_a, shared_b, tol) -> np.ndarray:
    """Whether coplanar triangles (k, 3, 3) overlap in their plane: a proper crossing of two edges that
    share no vertex, or an unshared vertex of one strictly inside the other."""
    normal = np.cross(pa[:, 1] - pa[:, 0], pa[:, 2] - pa[:, 0])
    drop = np.abs(normal).argmax(axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[drop]
    a2 = np.take_along_axis(pa, keep[:, None, :], axis=2)
    b2 = np.take_along_axis(pb, keep[:, None, :], axis=2)
    cross2 = lambda o, x, y: (x[:, 0] - o[:, 0]) * (y[:, 1] - o[:, 1]) - (x[:, 1] - o[:, 1]) * (y[:, 0] - o[:, 0])  # noqa: E731
    hit = np.zeros(len(pa), dtype=bool)
    for i in range(3):
        for j in range(3):
            p, q, r, s = a2[:, i], a2[:, (i + 1) % 3], b2[:, j], b2[:, (j + 1) % 3]
            free = ~(shared_a[:, i] | shared_a[:, (i + 1) % 3]) | ~(shared_b[:, j] | shared_b[:, (j + 1) % 3])
            d1, d2, d3, d4 = cross2(p, q, r), cross2(p, q, s), cross2(r, s, p), cross2(r, s, q)
            hit |= free & (d1 * d2 < -tol) & (d3 * d4 < -tol)
    for x2, y2, shared_x in ((a2, b2, shared_a), (b2, a2, shared_b)):
        for i in range(3):
            e = np.stack([cross2(y2[:, k], y2[:, (k + 1) % 3], x2[:, i]) for k in range(3)], axis=1)
            hit |= ~shared_x[:, i] & ((e > tol).all(axis=1) | (e < -tol).all(axis=1))
    return hit


def crossing_triangles(v: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Mask (m,) of the triangles that cross, overlap or duplicate another: what TetGen refuses as a PLC.

    Triangles that share an edge may only fold onto each other (angle between them under 1 degree);
    triangles sharing one vertex are tested by their opposite edges; others by all six edges and, if
    coplanar, in their plane.
    """
    pairs = _candidate_pairs(v, tri)
    A, B = tri[pairs[:, 0]], tri[pairs[:, 1]]
    shared_a = (A[:, :, None] == B[:, None, :]).any(axis=2)  # (k, 3) vertex of A also in B
    shared_b = (B[:, :, None] == A[:, None, :]).any(axis=2)
    n_shared = shared_a.sum(axis=1)
    pa, pb = v[A], v[B]
    scale = float(np.ptp(v, axis=0).max())
    tol = 1e-12 * scale**3
    bad = n_shared == 3
    e2 = n_shared == 2
    if e2.any():  # folded: the two opposite vertices on the same side of the shared edge, in one plane
        ia, ib = (~shared_a[e2]).argmax(axis=1), (~shared_b[e2]).argmax(axis=1)
        sa = np.argwhere(shared_a[e2])[:, 1].reshape(-1, 2)
        k = np.arange(e2.sum())
        p0, p1 = pa[e2][k, sa[:, 0]], pa[e2][k, sa[:, 1]]
        axis = (p1 - p0) / np.linalg.norm(p1 - p0, axis=1, keepdims=True)
        oa, ob = pa[e2][k, ia] - p0, pb[e2][k, ib] - p0
        oa -= np.einsum("ij,ij->i", oa, axis)[:, None] * axis
        ob -= np.einsum("ij,ij->i", ob, axis)[:, None] * axis
        cos = np.einsum("ij,ij->i", oa, ob) / (np.linalg.norm(oa, axis=1) * np.linalg.norm(ob, axis=1))
        bad[e2] = cos > np.cos(np.radians(1.0))
    rest = n_shared <= 1
    if rest.any():
        ra, rb, sha, shb = pa[rest], pb[rest], shared_a[rest], shared_b[rest]
        hit = np.zeros(rest.sum(), dtype=bool)
        for x, y, shx in ((ra, rb, sha), (rb, ra, shb)):
            for i in range(3):
                j = (i + 1) % 3
                free = ~(shx[:, i] | shx[:, j])  # an edge through the shared vertex only touches
                hit |= free & _segment_hits(x[:, i], x[:, j], y[:, 0], y[:, 1], y[:, 2], tol)
        na = np.cross(ra[:, 1] - ra[:, 0], ra[:, 2] - ra[:, 0])
        planar = np.stack([np.abs(_orient(ra[:, 0], ra[:, 1], ra[:, 2], rb[:, i])) for i in range(3)],
                          axis=1).max(axis=1)
        coplanar = planar <= 1e-9 * np.linalg.norm(na, axis=1) * scale
        if coplanar.any():
            hit[coplanar] |= _coplanar_overlap(ra[coplanar], rb[coplanar], sha[coplanar], shb[coplanar], tol)
        bad[rest] = hit
    mask = np.zeros(len(tri), dtype=bool)
    mask[pairs[bad].ravel()] = True
    return mask
