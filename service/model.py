"""The predictor: a model folder (contracts.model, read with every hash checked) answered with onnxruntime.

Only numpy, scipy and onnxruntime here: the service never imports torch, gmsh or FE code.
"""

from __future__ import annotations

import logging
import numpy as np

from contracts.interpolate import PointLocator, interpolate
from contracts.model import ModelError, ModelFolder, ModelManifest, check_graph, onnx_session, read_model_folder

from .materials import budget_parts

log = logging.getLogger(__name__)
__all__ = ["ModelError", "ModelFolder", "check_graph", "onnx_session", "OutsideMesh", "PointLocator", "Predictor",
           "read_model_folder"]


class OutsideMesh(ValueError):
    """A query point lies in no tet of the mesh."""

    def __init__(self, index: int, point: list[float]):
        super().__init__(f"points[{index}] = {point} is outside the mesh")
        self.index, self.point = index, point


class Predictor:
    """Decode displacements for all nodes, a region, or interior points."""

    def __init__(self, folder: ModelFolder, *, threads: int = 1, session=None):
        """`session`: the folder's onnxruntime session when the caller opened it already (else one with `threads`)."""
        self.folder = folder
        self.session = session or onnx_session(folder.path / "model.onnx", threads=threads)
        self.locator = PointLocator(folder.nodes, folder.tets)
        self.nodes32 = folder.nodes.astype(np.float32)
        # the error budget's per-region bounds, from the manifest once (not per request); {} without materials
        self.budget_parts = budget_parts(folder.manifest)

    @property
    def manifest(self) -> ModelManifest:
        return self.folder.manifest

    def decode(self, guides: np.ndarray, nodes: np.ndarray | None = None) -> np.ndarray:
        """(batch, k, 3) float32 displacement in mm of `nodes` (all nodes when None) for each
        [displacement_mm, angle_deg] row of `guides` (batch, 2): one onnxruntime call, one pass over the basis."""
        feed = {"guide": np.asarray(guides, dtype=np.float32).reshape(-1, 2)}
        if nodes is not None:
            feed["nodes"] = np.asarray(nodes, dtype=np.int64)
        return self.session.run(None, feed)[0]

    def decode_std(self, guides: np.ndarray, nodes: np.ndarray | None,
                   materials: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A material model's (displacement, std), each (batch, k, 3) float32 mm; `materials` (batch, 2, m): theta
        = ln(E/E_nominal) and the std of ln E per tissue (service/materials.py)."""
        feed = {"guide": np.asarray(guides, dtype=np.float32).reshape(-1, 2),
                "materials": np.ascontiguousarray(materials[:, 0], dtype=np.float32),
                "materials_std": np.ascontiguousarray(materials[:, 1], dtype=np.float32)}
        if nodes is not None:
            feed["nodes"] = np.asarray(nodes, dtype=np.int64)
        u, std = self.session.run(["displacement", "displacement_std"], feed)
        return u, std

    def displacement(self, displacement_mm: float, angle_deg: float, nodes: np.ndarray | None = None) -> np.ndarray:
        """(k, 3) float32 displacement in mm of `nodes` (all nodes when None)."""
        return self.decode(np.array([[displacement_mm, angle_deg]]), nodes)[0]

    def locate(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The nodes that interpolate at `points`: (unique node ids, (k, 10) index into them, (k, 4) barycentric).

        Raises OutsideMesh naming the first point that lies in no tet.
        """
        tet, bary = self.locator.locate(points)
        if (tet < 0).any():
            first = int(np.flatnonzero(tet < 0)[0])
            raise OutsideMesh(first, np.asarray(points)[first].tolist())
        ids = self.folder.tets[tet]  # (k, 10)
        unique, inverse = np.unique(ids, return_inverse=True)
        return unique, inverse.reshape(ids.shape), bary

    def at_points(self, displacement_mm: float, angle_deg: float, points: np.ndarray) -> np.ndarray:
        """(k, 3) displacement at reference points, interpolated with the containing tet's P2 shape functions."""
        unique, inverse, bary = self.locate(points)
        u = self.displacement(displacement_mm, angle_deg, unique)[inverse]  # (k, 10, 3)
        return interpolate(u, bary).astype(np.float32)
