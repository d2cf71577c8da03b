"""The deformed mesh as files other tools open: VTU (the volume) for ParaView and 3D Slicer,
PLY and GLB (tissue surfaces).

Pure functions of a model folder and a displacement field (n_nodes, 3) in mm. Coordinates stay in
the mesh frame and in millimetres, GLB included (glTF assumes metres: scale by 0.001 on import
where that matters). meshio and trimesh are imported inside the writers, so `import service`
loads neither and the JSON path of /predict never pays for them.

    vtu  every tet10 with cell data `tissue` (an index into the model's tissue names, in
         GET /model's mesh.tissues) and, so that the names are in the file, `tissue_<name>` for
         each tissue (1 on its cells, else 0: ParaView's Threshold or Slicer's scalars pick a
         tissue by name; meshio's VTU writer drops field data, where a name table would go);
         point data `displacement` (mm)
    ply  one triangle mesh: every tissue's outward surface, vertex property `node_id` (the mesh
         node), face property `tissue`, a colour per tissue
    glb  one named mesh per tissue (its outward surface), units "mm"
"""

from __future__ import annotations

import tempfile
from enum import Enum
from pathlib import Path

import numpy as np
from fastapi.responses import Response

from contracts.model import ModelFolder

from ..http import error_reply

# RGBA per tissue for the surface formats; a tissue not listed is grey.
TISSUE_COLOURS = {"prostate": (214, 96, 77, 255), "rectal_wall": (166, 97, 26, 255), "bladder": (80, 140, 200, 255),
                  "pubic_bone": (230, 226, 210, 255), "spine": (230, 226, 210, 255), "adipose": (250, 220, 120, 60)}


class ExportFormat(str, Enum):
    vtu = "vtu"
    ply = "ply"
    glb = "glb"


MEDIA_TYPES = {ExportFormat.vtu: "application/xml", ExportFormat.ply: "application/octet-stream",
               ExportFormat.glb: "model/gltf-binary"}


def surface_of(folder: ModelFolder, tissue: str) -> tuple[np.ndarray, np.ndarray]:
    """(node ids (k,), triangles (m, 3) indexing those ids) of one tissue's outward corner surface."""
    node_ids, local = np.unique(folder.surfaces[tissue], return_inverse=True)
    return node_ids, local.reshape(-1, 3).astype(np.int32)


def vtu_bytes(folder: ModelFolder, displacement: np.ndarray) -> bytes:
    """The deformed tet10 volume as a VTU file (zlib-compressed binary)."""
    import meshio

    mesh = folder.mesh
    u = np.asarray(displacement, dtype=np.float32)
    cells = [("tetra10", mesh.tets.astype(np.int64))]
    tissue = mesh.tissue.astype(np.int32)
    named = {f"tissue_{name}": [(tissue == i).astype(np.uint8)] for i, name in enumerate(folder.manifest.mesh.tissues)}
    out = meshio.Mesh(folder.nodes.astype(np.float32) + u, cells, point_data={"displacement": u},
                      cell_data={"tissue": [tissue], **named})
    with tempfile.TemporaryDirectory() as tmp:  # meshio's VTU writer takes a path, not a buffer
        path = Path(tmp) / "mesh.vtu"
        meshio.write(path, out, file_format="vtu")
        return path.read_bytes()


def _surface_meshes(folder: ModelFolder, displacement: np.ndarray):
    import trimesh

    positions = folder.nodes.astype(np.float32) + np.asarray(displacement, dtype=np.float32)
    for name in folder.manifest.mesh.tissues:
        if name not in folder.surfaces:
            continue
        ids, faces = surface_of(folder, name)
        colour = np.array(TISSUE_COLOURS.get(name, (160, 160, 160, 255)), dtype=np.uint8)
        yield name, ids, trimesh.Trimesh(positions[ids], faces, vertex_colors=np.tile(colour, (len(ids), 1)),
                                         process=False, validate=False)


def ply_bytes(folder: ModelFolder, displacement: np.ndarray) -> bytes:
    """Every tissue's deformed surface in one binary PLY, with `node_id` per vertex and `tissue` per face."""
    import trimesh

    index = {name: i for i, name in enumerate(folder.manifest.mesh.tissues)}
    parts, node_ids, tissue = [], [], []
    for name, ids, part in _surface_meshes(folder, displacement):
        parts.append(part)
        node_ids.append(ids)
        tissue.append(np.full(len(part.faces), index[name], dtype=np.uint8))
    joined = trimesh.util.concatenate(parts)
    joined.vertex_attributes["node_id"] = np.concatenate(node_ids).astype(np.int32)
    joined.face_attributes["tissue"] = np.concatenate(tissue)
    return trimesh.exchange.ply.export_ply(joined, encoding="binary", include_attributes=True)


def glb_bytes(folder: ModelFolder, displacement: np.ndarray) -> bytes:
    """Each tissue's deformed surface as a named mesh in one GLB scene."""
    import trimesh

    scene = trimesh.Scene()
    for name, _, part in _surface_meshes(folder, displacement):
        part.units = "mm"
        scene.add_geometry(part, geom_name=name, node_name=name)
    return trimesh.exchange.gltf.export_glb(scene)


WRITERS = {ExportFormat.vtu: vtu_bytes, ExportFormat.ply: ply_bytes, ExportFormat.glb: glb_bytes}


def export_bytes(folder: ModelFolder, displacement: np.ndarray, fmt: ExportFormat | str) -> bytes:
    """The deformed mesh in `fmt` (vtu, ply or glb)."""
    return WRITERS[ExportFormat(fmt)](folder, displacement)


def export_filename(model: str, displacement_mm: float, angle_deg: float, fmt: ExportFormat | str) -> str:
    """`default_d5mm_b-2deg.vtu`: what the file holds, in its name."""
    return f"{model}_d{displacement_mm:g}mm_b{angle_deg:g}deg.{ExportFormat(fmt).value}"


def export_response(predictor, *, displacement_mm: float, angle_deg: float, fmt: ExportFormat,
                    region: str | None, points) -> Response:
    """POST /predict?format=...: the deformed mesh as an attachment; 422 when region or points are given too."""
    if region is not None or points is not None:
        return error_reply(422, [("format", "format: a file holds the whole mesh; leave out region and points "
                                            "(or leave out format)", "format_conflict")])
    folder = predictor.folder
    body = export_bytes(folder, predictor.displacement(displacement_mm, angle_deg), fmt)
    name = export_filename(folder.manifest.name, displacement_mm, angle_deg, fmt)
    return Response(body, media_type=MEDIA_TYPES[fmt], headers={
        "Content-Disposition": f'attachment; filename="{name}"', "X-Tissues": ",".join(folder.manifest.mesh.tissues)})


# The reply's other content types in /predict's OpenAPI entry (schemathesis checks replies against it), in
# MEDIA_TYPES' order: a set's order changes with the process's hash seed, and the document with it.
EXPORT_CONTENT = {media: {"schema": {"type": "string", "format": "binary"}}
                  for media in dict.fromkeys(MEDIA_TYPES.values())}
