"""Write a model folder atomically: model.onnx, mesh.npz, manifest.json (with sha256 of each file), report.md.

The folder is assembled next to its destination and swapped in with two renames, so a crash
while exporting leaves the previous model as it was. `service.model.load_model_folder` reads it back
and checks the hashes.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from fem_offline.mesh import TetMesh

FORMAT_VERSION = 1
_FACES = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])


def sha256(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def tissue_surfaces(mesh: TetMesh) -> dict[str, np.ndarray]:
    """Corner triangles (k, 3) bounding each tissue, oriented outwards, for drawing."""
    out = {}
    for t, name in enumerate(mesh.tissue_names):
        tets = mesh.tets[mesh.tissue == t, :4]
        if not len(tets):
            continue
        tri = tets[:, _FACES].reshape(-1, 3)
        opposite = tets[:, [3, 2, 1, 0]].reshape(-1)  # the vertex not on each face
        key = np.sort(tri, axis=1)
        _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        once = counts[inverse.ravel()] == 1
        tri, opposite = tri[once], opposite[once]
        p = mesh.nodes
        normal = np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]])
        inward = np.einsum("ij,ij->i", normal, p[opposite] - p[tri[:, 0]]) > 0
        tri[inward] = tri[inward][:, [0, 2, 1]]
        out[name] = tri.astype(np.int32)
    return out


def regions(mesh: TetMesh) -> dict[str, np.ndarray]:
    """Named node sets the service can decode alone: each tissue, then the mesh's own sets."""
    out = {name: np.unique(mesh.tets[mesh.tissue == t]) for t, name in enumerate(mesh.tissue_names)}
    out.update({name: np.asarray(ids) for name, ids in mesh.node_sets.items()})
    return {name: ids.astype(np.int64) for name, ids in out.items() if len(ids)}


def write_mesh(mesh: TetMesh, path: Path) -> dict[str, int]:
    """Reference nodes, tets, tissue tags, regions and tissue surfaces in one .npz; region sizes back."""
    arrays = {"nodes": mesh.nodes, "tets": mesh.tets.astype(np.int32), "tissue": mesh.tissue.astype(np.int8)}
    sets = regions(mesh)
    arrays.update({f"region/{k}": v for k, v in sets.items()})
    arrays.update({f"surface/{k}": v for k, v in tissue_surfaces(mesh).items()})
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)
    return {k: int(len(v)) for k, v in sets.items()}


def write_model_folder(out: Path, *, onnx_bytes: bytes, mesh: TetMesh, manifest: dict, report: str) -> dict:
    """Write everything into a temporary sibling folder, then swap it in; returns the final manifest."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        (tmp / "model.onnx").write_bytes(onnx_bytes)
        manifest = {**manifest, "format_version": FORMAT_VERSION}
        manifest["regions"] = write_mesh(mesh, tmp / "mesh.npz")
        (tmp / "report.md").write_text(report)
        manifest["files"] = {name: sha256(tmp / name) for name in ("model.onnx", "mesh.npz", "report.md")}
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
        for f in tmp.iterdir():
            with open(f, "rb") as fh:
                os.fsync(fh.fileno())
        old = out.with_name(f".{out.name}.old-{os.getpid()}")
        if out.exists():
            os.rename(out, old)
        os.rename(tmp, out)
        shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return manifest
