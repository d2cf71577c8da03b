"""Hertz's sphere on a half-space: the guide tip's contact (fe/contact.py) against the classical solution."""

from types import SimpleNamespace

import numpy as np
import pytest
from skfem import MeshTet

from fem_offline.fe import contact as ct
from fem_offline.fe.assembly import build_pattern
from fem_offline.fe.continuation import PathState, advance
from fem_offline.fe.materials import lame_kpa
from fem_offline.fe.newton import Stats
from fem_offline.fe.problem import Problem
from fem_offline.scene import load_scene

from ..conftest import SCENES
from ..fe_helpers import p2_data

E, R, DELTA = 10.0, 10.0, 0.1  # kPa, mm, mm: contact radius a = sqrt(R delta) = 1 mm
SIZE = 20.0  # the quarter block's side, 20 a


def _graded(fine_mm: float, fine_to: float, growth: float) -> np.ndarray:
    """0, fine_mm, ... fine_to, then cells growing by `growth` up to SIZE."""
    x = list(np.arange(0.0, fine_to + 1e-9, fine_mm))
    h = fine_mm
    while x[-1] < SIZE:
        h *= growth
        x.append(min(x[-1] + h, SIZE) if SIZE - x[-1] - h > 0.5 * h else SIZE)
    return np.array(x)


def _quarter_block() -> MeshTet:
    """[0, SIZE]^2 x [-SIZE, 0], cells of 0.2 mm over the contact (radius 1 mm) growing away from it."""
    s = _graded(0.2, 1.4, 1.45)
    return MeshTet.init_tensor(s, s, np.sort(-_graded(0.25, 1.0, 1.6)))


def _indent(volumetric: str, nu: float):
    """The resultant (mN) and contact radius (mm) of a rigid sphere pushed DELTA into the block's top (small strain)."""
    mesh = _quarter_block()
    nodes, tets, G, W, _ = p2_data(mesh)
    n = len(nodes)
    # symmetry planes x = 0 and y = 0, the bottom slides on z = -SIZE
    fixed = np.concatenate([3 * np.flatnonzero(np.abs(nodes[:, 0]) < 1e-12),
                            3 * np.flatnonzero(np.abs(nodes[:, 1]) < 1e-12) + 1,
                            3 * np.flatnonzero(np.abs(nodes[:, 2] + SIZE) < 1e-12) + 2])
    free = np.setdiff1d(np.arange(3 * n), fixed)
    mu, lam = lame_kpa(E, nu)
    top = mesh.facets_satisfying(lambda x: (x[2] > -1e-12) & (x[0] < 2.0) & (x[1] < 2.0), boundaries_only=True)
    active = np.ones(len(tets), bool)
    surface = ct.facet_surface(mesh, top, tets, active, rest_centre=np.array([0.0, 0.0, R]), radius_mm=R,
                               stiffness=1e4, tol_mm=1e-5)
    scene = load_scene(SCENES / "tiny.toml")
    scene = scene.model_copy(update={
        "effects": scene.effects.model_copy(update={"guide_contact": True, "geometric_nonlinearity": False}),
        "guide": scene.guide.model_copy(update={"axis": (0.0, 0.0, -1.0), "tilt_normal": (1.0, 0.0, 0.0)}),
        "solver": scene.solver.model_copy(update={"volumetric": volumetric})})
    p = Problem(scene, SimpleNamespace(nodes=nodes), G, W, np.full(len(tets), mu), np.full(len(tets), lam),
                build_pattern(tets, n, free), fixed, np.zeros((0, 3), int), np.zeros(0), None, active, surface)
    state, stats = advance(p, PathState(np.zeros(3 * n)), DELTA, 0.0, Stats())
    touch = ct.evaluate(surface, state.u, p.at_guide(DELTA, 0.0, state.multipliers).contact_load)
    x = surface.X[..., :2]
    radius = float(np.linalg.norm(x[touch.pressure > 0], axis=1).max())
    return 4 * ct.resultant(surface, touch)[2], radius, stats


@pytest.mark.slow
@pytest.mark.parametrize("volumetric, nu", [("pointwise", 0.3), ("mean_dilatation", 0.495)])
def test_sphere_on_a_half_space_gives_hertz_force_and_contact_radius(volumetric, nu):
    """F = 4/3 E* sqrt(R) delta^(3/2), E* = E / (1 - nu^2), and a = sqrt(R delta) (Johnson, Contact Mechanics, 4.2)."""
    force, radius, stats = _indent(volumetric, nu)
    hertz = 4 / 3 * E / (1 - nu**2) * np.sqrt(R) * DELTA**1.5
    assert stats.penetration_mm <= 1e-5
    assert stats.contact_updates >= 1
    # the quarter block is 20 a wide and deep: the half-space's far field it leaves out makes it stiffer by some
    # per cent (a point load's surface displacement at 20 a is 3 % of delta)
    assert 1.0 <= force / hertz <= 1.07
    assert radius == pytest.approx(np.sqrt(R * DELTA), rel=0.05)  # the quadrature points resolve a to ~0.05 mm
