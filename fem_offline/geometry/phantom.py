"""Synthetic male pelvis built with gmsh's OCC kernel and meshed into tetrahedra.

Coordinates in mm: x lateral (the phantom is mirror-symmetric about x = 0), y posterior ->
anterior, z up from the table at z = 0. Tissues: adipose block; prostate ellipsoid; bladder
sphere superior to it; rectal wall as a tube along z with an open lumen posterior to the
prostate; pubic bone (a bar along x) anterior; spine/sacrum (a slab) posterior. All interfaces
are bonded: the volumes are boolean fragments of one another and share one conforming mesh.
"""

from __future__ import annotations

import logging
from contextlib import contextmanager

import numpy as np

from fem_offline.scene import Phantom, Scene

log = logging.getLogger(__name__)

# Where two input shapes overlap, the piece belongs to the earlier tissue here.
PRIORITY = ("pubic_bone", "spine", "prostate", "bladder", "rectal_wall", "adipose")


@contextmanager
def _gmsh_session():
    import gmsh

    gmsh.initialize(interruptible=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", 1)
    try:
        yield gmsh
    finally:
        gmsh.finalize()


def _sphere(occ, centre, radius: float) -> int:
    """A sphere with its poles on the x axis, so the mirror plane x = 0 cuts its equator, not its poles."""
    tag = occ.addSphere(*centre, radius)
    occ.rotate([(3, tag)], *centre, 0.0, 1.0, 0.0, np.pi / 2)
    return tag


def _add_shapes(occ, ph: Phantom) -> dict[str, int]:
    """Add one OCC volume per tissue; the lumen is already cut from the block."""
    bx, by, bz = ph.block_mm
    rx, ry = ph.rectum_center_xy_mm
    block = occ.addBox(-bx / 2, -by / 2, 0.0, bx, by, bz)
    lumen = occ.addCylinder(rx, ry, 0.0, 0.0, 0.0, bz, ph.rectum_inner_radius_mm)
    rectum = occ.addCylinder(rx, ry, 0.0, 0.0, 0.0, bz, ph.rectum_outer_radius_mm)
    (block_cut, _) = occ.cut([(3, block)], [(3, lumen)], removeTool=False)
    (wall, _) = occ.cut([(3, rectum)], [(3, lumen)])
    prostate = _sphere(occ, ph.prostate_center_mm, 1.0)
    occ.dilate([(3, prostate)], *ph.prostate_center_mm, *ph.prostate_semi_axes_mm)
    bladder = _sphere(occ, ph.bladder_center_mm, ph.bladder_radius_mm)
    px, py, pz = ph.pubic_center_mm
    pubic = occ.addCylinder(px - ph.pubic_length_mm / 2, py, pz, ph.pubic_length_mm, 0, 0, ph.pubic_radius_mm)
    (lo, hi) = np.asarray(ph.spine_box_mm)
    spine = occ.addBox(*lo, *(hi - lo))
    return {
        "adipose": block_cut[0][1],
        "rectal_wall": wall[0][1],
        "prostate": prostate,
        "bladder": bladder,
        "pubic_bone": pubic,
        "spine": spine,
    }


def is_symmetric(scene: Scene) -> bool:
    """True when phantom and guide tip are mirror-symmetric about x = 0 (then half is meshed and mirrored)."""
    ph = scene.phantom
    xs = [ph.prostate_center_mm[0], ph.bladder_center_mm[0], ph.rectum_center_xy_mm[0], ph.pubic_center_mm[0]]
    spine = np.asarray(ph.spine_box_mm)
    return all(x == 0 for x in xs) and spine[0, 0] == -spine[1, 0] and scene.guide.tip_mm[0] == 0


def _keep_half(occ, shapes: dict[str, int], ph: Phantom) -> dict[str, int]:
    """Intersect every shape with the half-space x >= 0."""
    bx, by, bz = ph.block_mm
    halves = {}
    for name, tag in shapes.items():
        box = occ.addBox(0.0, -by, -1.0, bx, 2 * by, bz + 2)
        (out, _) = occ.intersect([(3, tag)], [(3, box)])
        halves[name] = out[0][1]
    return halves


def _mirror(points: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reflect a half mesh (x >= 0) across x = 0, sharing the nodes on the plane."""
    on_plane = np.abs(points[:, 0]) <= 1e-9 * np.abs(points).max()
    image = np.arange(len(points)) + len(points)
    image[on_plane] = np.flatnonzero(on_plane)
    mirrored = points * np.array([-1.0, 1.0, 1.0])
    return np.vstack([points, mirrored]), np.vstack([tets, image[tets]])


def _fragment(occ, shapes: dict[str, int]) -> dict[str, list[int]]:
    """Fragment all shapes into one conforming set; give each piece to its first-priority tissue."""
    names = list(shapes)
    objects = [(3, shapes[n]) for n in names]
    _, piece_map = occ.fragment(objects[:1], objects[1:])
    owner: dict[int, str] = {}
    for name in sorted(names, key=PRIORITY.index, reverse=True):
        for _dim, tag in piece_map[names.index(name)]:
            owner[tag] = name  # later (higher-priority) names overwrite
    occ.synchronize()
    pieces: dict[str, list[int]] = {n: [] for n in names}
    for tag, name in owner.items():
        pieces[name].append(tag)
    return pieces


def _threshold(field, distance: int, *, size_min: float, size_max: float, dist_max_mm: float) -> int:
    """A gmsh Threshold field: size_min on the distance field's surfaces, growing to size_max at dist_max_mm."""
    tag = field.add("Threshold")
    field.setNumber(tag, "InField", distance)
    field.setNumber(tag, "SizeMin", size_min)
    field.setNumber(tag, "SizeMax", size_max)
    field.setNumber(tag, "DistMin", 0.0)
    field.setNumber(tag, "DistMax", dist_max_mm)
    return tag


def _size_field(gmsh, scene: Scene, pieces: dict[str, list[int]]) -> None:
    """Fine near the prostate and the guide tip, coarse far away."""
    size = scene.mesh
    field = gmsh.model.mesh.field
    prostate_faces = [t for _, t in gmsh.model.getBoundary([(3, v) for v in pieces["prostate"]], oriented=False)]
    dist = field.add("Distance")
    field.setNumbers(dist, "SurfacesList", prostate_faces)
    near = _threshold(field, dist, size_min=size.prostate_mm, size_max=size.max_mm, dist_max_mm=25.0)
    tip = field.add("Ball")
    field.setNumber(tip, "Radius", 1.5 * scene.guide.patch_radius_mm)
    field.setNumber(tip, "Thickness", 2.0 * scene.guide.patch_radius_mm)
    for axis, value in zip("XYZ", scene.guide.tip_mm):
        field.setNumber(tip, f"{axis}Center", value)
    field.setNumber(tip, "VIn", size.guide_mm)
    field.setNumber(tip, "VOut", size.max_mm)
    fields = [near, tip]
    if size.surface_near_tip_mm is not None:  # the prostate's surface near the tip: a fine shell, cut to a ball
        fine = field.add("Distance")  # sampled finely enough for sub-mm sizes (the default 20 per direction is not)
        field.setNumbers(fine, "SurfacesList", prostate_faces)
        field.setNumber(fine, "Sampling", 200)
        shell = _threshold(field, fine, size_min=size.surface_near_tip_mm, size_max=size.max_mm, dist_max_mm=5.0)
        zone = field.add("Ball")  # max_mm outside: Max(shell, zone) is the shell inside the ball only
        field.setNumber(zone, "Radius", 2.0 * scene.guide.patch_radius_mm)
        field.setNumber(zone, "Thickness", scene.guide.patch_radius_mm)
        for axis, value in zip("XYZ", scene.guide.tip_mm):
            field.setNumber(zone, f"{axis}Center", value)
        field.setNumber(zone, "VIn", size.surface_near_tip_mm)
        field.setNumber(zone, "VOut", size.max_mm)
        cut = field.add("Max")
        field.setNumbers(cut, "FieldsList", [shell, zone])
        fields.append(cut)
    both = field.add("Min")
    field.setNumbers(both, "FieldsList", fields)
    field.setAsBackgroundMesh(both)
    for opt in ("MeshSizeFromPoints", "MeshSizeFromCurvature", "MeshSizeExtendFromBoundary"):
        gmsh.option.setNumber(f"Mesh.{opt}", 0)


def build_phantom(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[str, ...]]:
    """Mesh the phantom; return nodes (n, 3), corner tets (m, 4), tissue ids (m,), names.

    A mirror-symmetric scene is meshed on x >= 0 and reflected, so the mesh itself is symmetric
    and beta -> -beta mirrors the discrete solution exactly.

    gmsh meshes first order; mesh.from_vertices adds the P2 edge nodes at the edge midpoints
    (straight-sided: gmsh's curved P2 tets came out with inverted elements on this geometry).
    """
    if scene.phantom is None:
        raise ValueError("scene has no [phantom] section")
    with _gmsh_session() as gmsh:
        gmsh.model.add("pelvis")
        symmetric = is_symmetric(scene)
        shapes = _add_shapes(gmsh.model.occ, scene.phantom)
        if symmetric:
            shapes = _keep_half(gmsh.model.occ, shapes, scene.phantom)
        pieces = _fragment(gmsh.model.occ, shapes)
        names = tuple(n for n in PRIORITY if pieces[n])
        for i, name in enumerate(names):
            gmsh.model.addPhysicalGroup(3, pieces[name], tag=i + 1, name=name)
        _size_field(gmsh, scene, pieces)
        gmsh.option.setNumber("Mesh.Optimize", 1)
        gmsh.model.mesh.generate(3)
        node_tags, coords, _ = gmsh.model.mesh.getNodes()
        index = np.zeros(int(node_tags.max()) + 1, dtype=np.int64)
        index[node_tags.astype(np.int64)] = np.arange(node_tags.size)
        tets, tissue = [], []
        for i, name in enumerate(names):
            for vol in pieces[name]:
                etypes, _, enodes = gmsh.model.mesh.getElements(3, vol)
                for etype, nodes in zip(etypes, enodes):
                    if etype != 4:  # 4 = 4-node tetrahedron
                        raise RuntimeError(f"unexpected gmsh element type {etype}")
                    t = index[np.asarray(nodes, dtype=np.int64)].reshape(-1, 4)
                    tets.append(t)
                    tissue.append(np.full(len(t), i))
    points, tets, tissue = coords.reshape(-1, 3), np.vstack(tets), np.concatenate(tissue)
    if symmetric:
        points, tets = _mirror(points, tets)
        tissue = np.concatenate([tissue, tissue])
    log.info("phantom: %d tets, %d nodes (mirrored half: %s)", len(tets), len(points), symmetric)
    return points, tets, tissue, names
