from pathlib import Path

import pytest

from fem_offline.geometry.meshing import mesh_for_scene
from fem_offline.fe.problem import build_problem
from fem_offline.scene import load_scene

SCENES = Path(__file__).resolve().parents[2] / "fem_offline" / "scenes"


@pytest.fixture(scope="session")
def tiny_scene():
    return load_scene(SCENES / "tiny.toml")


@pytest.fixture(scope="session")
def tiny_mesh(tiny_scene):
    return mesh_for_scene(tiny_scene)


@pytest.fixture(scope="session")
def tiny_problem(tiny_scene, tiny_mesh):
    return build_problem(tiny_scene, tiny_mesh)


@pytest.fixture(scope="session")
def corner_path(tiny_problem):
    """beta = +10 deg, 2.5 ... 10 mm: the hard corner of the sweep."""
    from fem_offline.fe.continuation import solve_path

    return list(solve_path(tiny_problem, [2.5, 5.0, 7.5, 10.0], 10.0))


@pytest.fixture(scope="session")
def tiny_linear_problem(tiny_scene, tiny_mesh):
    effects = tiny_scene.effects.model_copy(update={"geometric_nonlinearity": False})
    scene = tiny_scene.model_copy(update={"effects": effects})
    return build_problem(scene, tiny_mesh)
