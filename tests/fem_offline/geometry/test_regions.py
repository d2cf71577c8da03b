"""Named node sets: markers on the prostate surface, table at z = 0, guide patch, every bone node."""

import numpy as np


def test_node_sets(tiny_mesh, tiny_scene):
    sets = tiny_mesh.node_sets
    assert len(sets["markers"]) == 8 and set(sets["markers"]) <= set(sets["prostate_surface"])
    assert np.allclose(tiny_mesh.nodes[sets["table"], 2], 0.0)
    tip = np.asarray(tiny_scene.guide.tip_mm)
    assert (np.linalg.norm(tiny_mesh.nodes[sets["guide_patch"]] - tip, axis=1) < tiny_scene.guide.patch_radius_mm).all()
    bone_ids = [tiny_mesh.tissue_names.index(n) for n in ("pubic_bone", "spine")]
    assert set(np.unique(tiny_mesh.tets[np.isin(tiny_mesh.tissue, bone_ids)])) == set(sets["bones"])
