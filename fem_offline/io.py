"""Atomic file writes and the mesh a scene describes."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from . import mesh as meshmod
from .regions import build_node_sets
from .scene import Scene


def atomic_savez(path: str | Path, **arrays) -> Path:
    """np.savez to a temporary file beside `path`, then rename: readers never see half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_json(path: str | Path, data: dict) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "w") as fh:
        json.dump(data, fh, indent=2)
    os.replace(tmp, path)
    return path


def mesh_for_scene(scene: Scene) -> meshmod.TetMesh:
    """Mesh the phantom with gmsh, or read the user's mesh; attach the named node sets."""
    if scene.mesh_file is not None:
        base = meshmod.read_user_mesh(scene)
    else:
        from .phantom import build_phantom

        base = meshmod.from_vertices(*build_phantom(scene))
    return build_node_sets(base, scene)


def load_or_build_mesh(scene: Scene, path: str | Path | None) -> meshmod.TetMesh:
    """Read a saved mesh (re-deriving node sets for this scene's guide) or build a new one."""
    if path is None:
        return mesh_for_scene(scene)
    path = Path(path)
    if not path.exists():
        raise ValueError(f"--mesh: no such file {path}")
    mesh = meshmod.load(path)
    missing = sorted(set(mesh.tissue_names) - set(scene.tissues))
    if missing:
        raise ValueError(f"--mesh: {path} has tissues {missing} that the scene does not define")
    return build_node_sets(mesh, scene)
