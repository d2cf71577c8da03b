"""Load a model folder (checking every hash) and answer queries with onnxruntime.

Only numpy, scipy and onnxruntime here: the service never imports torch, gmsh or FE code.
"""

from __future__ import annotations

import logging
import numpy as np

from contracts.model import ModelError, ModelFolder, ModelManifest, onnx_session, read_model_folder
from contracts.tet10 import p2_weights

log = logging.getLogger(__name__)
__all__ = ["ModelError", "ModelFolder", "OutsideMesh", "PointLocator", "Predictor", "p2_weights", "read_model_folder"]


class OutsideMesh(ValueError):
    """A query point lies in no tet of the mesh."""

    def __init__(self, index: int):
        super().__init__(f"points[{index}] is outside the mesh")
        self.index = index


class PointLocator:
    """Find the tet containing each query point (tets are straight-sided: barycentric test on corners)."""

    def __init__(self, nodes: np.ndarray, tets: np.ndarray, candidates: int = 16):
        from scipy.spatial import cKDTree

        corners = nodes[tets[:, :4]]  # (m, 4, 3)
        self._origin = corners[:, 3]
        t = (corners[:, :3] - corners[:, 3:4]).transpose(0, 2, 1)  # (m, 3, 3) columns v0-v3, v1-v3, v2-v3
        self._inverse = np.linalg.inv(t)
        self._tree = cKDTree(corners.mean(axis=1))
        self._k = min(candidates, len(tets))
        self._lo, self._hi = nodes.min(axis=0), nodes.max(axis=0)

    def _bary(self, points: np.ndarray, tet: np.ndarray) -> np.ndarray:
        lam = np.einsum("...ij,...j->...i", self._inverse[tet], points - self._origin[tet])
        return np.concatenate([lam, 1.0 - lam.sum(axis=-1, keepdims=True)], axis=-1)

    def locate(self, points: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
        """Tet index (-1 where outside the mesh) and barycentric coordinates (k, 4) of each point."""
        points = np.asarray(points, dtype=np.float64)
        tet = np.full(len(points), -1)
        bary = np.zeros((len(points), 4))
        if not len(points):
            return tet, bary
        _, cand = self._tree.query(points, k=self._k)
        cand = cand.reshape(len(points), -1)
        lam = self._bary(points[:, None, :], cand)  # (k, c, 4)
        inside = lam.min(axis=-1) >= -tol
        hit = inside.any(axis=1)
        first = inside.argmax(axis=1)
        tet[hit] = cand[hit, first[hit]]
        bary[hit] = lam[hit, first[hit]]
        # Slivers can put the containing tet outside the nearest centroids: check the rest exhaustively.
        in_box = np.all((points >= self._lo - 1e-9) & (points <= self._hi + 1e-9), axis=1)
        for i in np.flatnonzero(~hit & in_box):
            lam_all = self._bary(points[i][None, :], np.arange(len(self._origin)))
            ok = np.flatnonzero(lam_all.min(axis=1) >= -tol)
            if len(ok):
                tet[i], bary[i] = ok[0], lam_all[ok[0]]
        return tet, np.clip(bary, 0.0, 1.0)


class Predictor:
    """Decode displacements for all nodes, a region, or interior points."""

    def __init__(self, folder: ModelFolder, *, threads: int = 1):
        self.folder = folder
        self.session = onnx_session(folder.path / "model.onnx", threads=threads)
        self.locator = PointLocator(folder.nodes, folder.tets)
        self.nodes32 = folder.nodes.astype(np.float32)

    @property
    def manifest(self) -> ModelManifest:
        return self.folder.manifest

    def displacement(self, displacement_mm: float, angle_deg: float, nodes: np.ndarray | None = None) -> np.ndarray:
        """(k, 3) float32 displacement in mm of `nodes` (all nodes when None)."""
        feed = {"guide": np.array([[displacement_mm, angle_deg]], dtype=np.float32)}
        if nodes is not None:
            feed["nodes"] = np.asarray(nodes, dtype=np.int64)
        return self.session.run(None, feed)[0][0]

    def at_points(self, displacement_mm: float, angle_deg: float, points: np.ndarray) -> np.ndarray:
        """(k, 3) displacement at reference points, interpolated with the containing tet's P2 shape functions."""
        tet, bary = self.locator.locate(points)
        if (tet < 0).any():
            raise OutsideMesh(int(np.flatnonzero(tet < 0)[0]))
        ids = self.folder.tets[tet]  # (k, 10)
        unique, inverse = np.unique(ids, return_inverse=True)
        u = self.displacement(displacement_mm, angle_deg, unique)[inverse.reshape(ids.shape)]  # (k, 10, 3)
        return np.einsum("kn,knd->kd", p2_weights(bary), u).astype(np.float32)
