"""Load a model folder (checking every hash) and answer queries with onnxruntime.

Only numpy, scipy and onnxruntime here: the service never imports torch, gmsh or FE code.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.interpolate import PointLocator, interpolate

log = logging.getLogger(__name__)

SUPPORTED_FORMAT = 1


class ModelError(ValueError):
    """The model folder is missing, corrupt or of another format."""


class OutsideMesh(ValueError):
    """A query point lies in no tet of the mesh."""

    def __init__(self, index: int, point: list[float]):
        super().__init__(f"points[{index}] = {point} is outside the mesh")
        self.index, self.point = index, point


def _sha256(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


@dataclass(frozen=True)
class ModelFolder:
    path: Path
    manifest: dict
    nodes: np.ndarray  # (n_nodes, 3) reference positions, mm
    tets: np.ndarray  # (n_tets, 10)
    tissue: np.ndarray  # (n_tets,)
    regions: dict[str, np.ndarray]  # name -> node ids
    surfaces: dict[str, np.ndarray]  # tissue -> (k, 3) corner triangles


def load_model_folder(path: str | Path) -> ModelFolder:
    """Read a folder written by `training fit`; refuse it if a file is missing or its sha256 differs."""
    path = Path(path)
    manifest_path = path / "manifest.json"
    if not manifest_path.is_file():
        raise ModelError(f"{path}: no manifest.json; is this a model folder written by `python -m training fit`?")
    try:
        manifest = json.loads(manifest_path.read_text())
    except json.JSONDecodeError as exc:
        raise ModelError(f"{manifest_path}: not valid JSON ({exc})") from None
    if manifest.get("format_version") != SUPPORTED_FORMAT:
        raise ModelError(f"{path}: format_version {manifest.get('format_version')!r}, this service reads {SUPPORTED_FORMAT}")
    for name, digest in manifest.get("files", {}).items():
        f = path / name
        if not f.is_file():
            raise ModelError(f"{path}: {name} is listed in the manifest but missing")
        if _sha256(f) != digest:
            raise ModelError(f"{path}: {name} does not match its sha256 in manifest.json (corrupt or replaced)")
    if not {"model.onnx", "mesh.npz"} <= set(manifest.get("files", {})):
        raise ModelError(f"{path}: the manifest must list model.onnx and mesh.npz")
    with np.load(path / "mesh.npz") as z:
        regions = {k.split("/", 1)[1]: z[k] for k in z.files if k.startswith("region/")}
        surfaces = {k.split("/", 1)[1]: z[k] for k in z.files if k.startswith("surface/")}
        folder = ModelFolder(path, manifest, z["nodes"], z["tets"], z["tissue"], regions, surfaces)
    if len(folder.nodes) != manifest["mesh"]["n_nodes"]:
        raise ModelError(f"{path}: mesh.npz has {len(folder.nodes)} nodes, the manifest says {manifest['mesh']['n_nodes']}")
    return folder


class Predictor:
    """Decode displacements for all nodes, a region, or interior points."""

    def __init__(self, folder: ModelFolder, *, threads: int = 1):
        import onnxruntime as ort

        self.folder = folder
        so = ort.SessionOptions()
        so.intra_op_num_threads = threads
        so.inter_op_num_threads = 1
        so.log_severity_level = 3  # the optional `nodes` input is an initializer by design
        self.session = ort.InferenceSession(str(folder.path / "model.onnx"), so, providers=["CPUExecutionProvider"])
        self.locator = PointLocator(folder.nodes, folder.tets)
        self.nodes32 = folder.nodes.astype(np.float32)

    @property
    def manifest(self) -> dict:
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
            first = int(np.flatnonzero(tet < 0)[0])
            raise OutsideMesh(first, np.asarray(points)[first].tolist())
        ids = self.folder.tets[tet]  # (k, 10)
        unique, inverse = np.unique(ids, return_inverse=True)
        u = self.displacement(displacement_mm, angle_deg, unique)[inverse.reshape(ids.shape)]  # (k, 10, 3)
        return interpolate(u, bary).astype(np.float32)
