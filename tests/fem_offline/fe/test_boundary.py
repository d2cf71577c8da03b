"""Boundary conditions: the table is a constraint only when switched on; bone tets are never assembled."""

import numpy as np

from fem_offline.fe.problem import build_problem


def test_table_constraint_only_when_switched_on(tiny_scene, tiny_mesh, tiny_problem):
    """Table on: u_z = 0 on the bottom face is a constraint; off: those DOFs are free. Bones are never assembled."""
    table_z = 3 * tiny_mesh.node_sets["table"] + 2
    assert np.isin(table_z, tiny_problem.fixed_dofs).all()
    effects = tiny_scene.effects.model_copy(update={"table": False})
    p = build_problem(tiny_scene.model_copy(update={"effects": effects}), tiny_mesh)
    bare = np.setdiff1d(table_z, 3 * tiny_mesh.node_sets["bones"] + 2)
    assert bare.size and not np.isin(bare, p.fixed_dofs).any()
    bone_ids = [tiny_mesh.tissue_names.index(n) for n in ("pubic_bone", "spine")]
    soft = (~np.isin(tiny_mesh.tissue, bone_ids)).sum()
    assert 0.95 * soft <= len(p.G) <= soft  # bone tets (all nodes fixed) are never assembled
