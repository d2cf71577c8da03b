"""The mesh a scene describes: the gmsh phantom, a user's tet mesh or a label map's, made P2,
with its named node sets."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fem_offline.geometry.mesh import TetMesh, from_vertices, load
from fem_offline.geometry.regions import build_node_sets
from fem_offline.scene import Scene


def mesh_for_scene(scene: Scene) -> TetMesh:
    """Mesh the phantom with gmsh, or read the user's mesh; attach the named node sets."""
    if scene.mesh_file is not None:
        base = read_user_mesh(scene)
    elif scene.label_map is not None:
        from fem_offline.labelmap.meshers import mesh_label_map

        base = from_vertices(*mesh_label_map(scene))
    else:
        from fem_offline.geometry.phantom import build_phantom

        base = from_vertices(*build_phantom(scene))
    return build_node_sets(base, scene)


def kept_mesh(scene: Scene, path: str | Path) -> TetMesh:
    """The scene's mesh saved at `path` (.npz), meshed and saved there first if it is not yet: gmsh is not
    bit-reproducible, so a sweep, a study level or a profiled path keeps the mesh it was solved on."""
    from contracts.mesh import read_mesh, write_mesh

    path = Path(path)
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        write_mesh(path, mesh_for_scene(scene))
    return read_mesh(path)


def load_or_build_mesh(scene: Scene, path: str | Path | None) -> TetMesh:
    """Read a saved mesh (re-deriving node sets for this scene's guide) or build a new one."""
    if path is None:
        return mesh_for_scene(scene)
    path = Path(path)
    if not path.exists():
        raise ValueError(f"--mesh: no such file {path}")
    mesh = load(path)
    missing = sorted(set(mesh.tissue_names) - set(scene.tissues))
    if missing:
        raise ValueError(f"--mesh: {path} has tissues {missing} that the scene does not define")
    return build_node_sets(mesh, scene)


def read_user_mesh(scene: Scene) -> TetMesh:
    """Read a user's tet mesh (tetra or tetra10, any meshio format) with tissue tags."""
    import meshio

    spec = scene.mesh_file
    try:
        m = meshio.read(spec.path)
    except (OSError, meshio.ReadError) as exc:
        raise ValueError(f"mesh_file.path: cannot read {spec.path}: {exc}") from None
    blocks = [(i, c) for i, c in enumerate(m.cells) if c.type in ("tetra", "tetra10")]
    if not blocks:
        raise ValueError(f"mesh_file.path: {spec.path} holds no tetrahedra")
    if spec.tag_field not in m.cell_data:
        raise ValueError(f"mesh_file.tag_field: {spec.tag_field!r} not in {sorted(m.cell_data)}")
    tets4 = np.vstack([c.data[:, :4] for _, c in blocks])
    tags = np.concatenate([m.cell_data[spec.tag_field][i] for i, _ in blocks])
    names = tuple(spec.tags)
    lookup = {v: k for k, v in enumerate(spec.tags.values())}
    unknown = sorted(set(np.unique(tags).tolist()) - set(lookup))
    if unknown:
        raise ValueError(f"mesh_file.tags: cell tags {unknown} are not mapped to a tissue")
    tissue = np.array([lookup[v] for v in tags.tolist()])
    return from_vertices(np.asarray(m.points, dtype=np.float64), tets4, tissue, names)
