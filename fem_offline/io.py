"""The mesh a scene describes: meshed from the phantom, read from the user's file, or reloaded."""

from __future__ import annotations

from pathlib import Path

from . import mesh as meshmod
from .regions import build_node_sets
from .scene import Scene


def mesh_for_scene(scene: Scene) -> meshmod.TetMesh:
    """Mesh the phantom with gmsh, or read the user's mesh; attach the named node sets."""
    if scene.mesh_file is not None:
        base = meshmod.read_user_mesh(scene)
    else:
        from .phantom import build_phantom

        points, tets10, tissue, names = build_phantom(scene)
        base = meshmod.from_vertices(points, tets10[:, :4], tissue, names)
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
