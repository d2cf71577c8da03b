"""Session fixtures every test folder shares: a tiny linear sweep and the model fitted on it (seconds)."""

import os
from pathlib import Path

import pytest

# Tests run several solver processes side by side on 2 cores; keep MKL to one thread each.
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

SCENES = Path(__file__).resolve().parents[1] / "fem_offline" / "scenes"
TINY_TEST_CASES = ((5.0, -2.0), (3.0, 4.0))


@pytest.fixture(scope="session")
def tiny_test_cases():
    return TINY_TEST_CASES


@pytest.fixture(scope="session")
def tiny_sweep(tmp_path_factory) -> Path:
    """A linear sweep of the tiny scene on a 1 mm x 2 deg grid (110 snapshots, superposition: fast).

    From 6 mm on its snapshots turn elements inside out (det(I + grad u) <= 0 at the 11 probe points
    per tet; at the solver's 4 from 7 mm; measured), so the model fitted on it (tiny_model) answers
    for 0..5 mm only: the service tests ask inside that."""
    from fem_offline.scene import load_scene
    from fem_offline.sweep import run_sweep

    scene = load_scene(SCENES / "tiny.toml", effects={"geometric_nonlinearity": False},
                       sweep={"displacement_step_mm": 1.0, "displacement_max_mm": 10.0, "angle_min_deg": -10.0,
                              "angle_max_deg": 10.0, "angle_step_deg": 2.0})
    out = tmp_path_factory.mktemp("sweep")
    manifest = run_sweep(scene, out)
    assert manifest.n_done == 110
    return out


@pytest.fixture(scope="session")
def tiny_model(tiny_sweep, tmp_path_factory) -> Path:
    from training.fit import FitOptions, fit

    out = tmp_path_factory.mktemp("models") / "tiny"
    fit(tiny_sweep, out, FitOptions(rank=8, max_iterations=300, test_cases=TINY_TEST_CASES), progress=False)
    return out


TINY_MATERIALS = {  # every soft tissue's stiffness as an input, around tiny.toml's (default.toml's) E
    "prostate": {"youngs_kpa_range": [50.0, 85.0], "std_percent": 20.0, "source": "test"},
    "rectal_wall": {"youngs_kpa_range": [140.0, 215.0], "std_percent": 20.0, "source": "test"},
    "adipose": {"youngs_kpa_range": [8.5, 13.5], "std_percent": 20.0, "source": "test"},
    "bladder": {"youngs_kpa_range": [80.0, 125.0], "std_percent": 20.0, "source": "test"},
}


def tiny_material_scene(**materials):
    """tiny.toml, linear and glued (superposable: seconds), with material inputs (default: TINY_MATERIALS)."""
    from fem_offline.scene import load_scene

    return load_scene(SCENES / "tiny.toml", effects={"geometric_nonlinearity": False, "guide_contact": False},
                      materials=materials or TINY_MATERIALS,
                      sweep={"displacement_step_mm": 1.0, "displacement_max_mm": 10.0, "angle_min_deg": -10.0,
                             "angle_max_deg": 10.0, "angle_step_deg": 2.0})


@pytest.fixture(scope="session")
def tiny_material_sweep(tmp_path_factory) -> Path:
    """tiny_sweep's grid, superposed, with S_i = du/d ln E_i of the four soft tissues in every snapshot."""
    from fem_offline.sweep import run_sweep

    out = tmp_path_factory.mktemp("material_sweep")
    assert run_sweep(tiny_material_scene(), out).n_done == 110
    return out


@pytest.fixture(scope="session")
def tiny_material_model(tiny_material_sweep, tmp_path_factory) -> Path:
    """A material model on tiny_material_sweep (answers for 0..5 mm, like tiny_model)."""
    from training.fit import FitOptions, fit

    out = tmp_path_factory.mktemp("models") / "tiny_materials"
    fit(tiny_material_sweep, out, FitOptions(rank=12, max_iterations=300, test_cases=TINY_TEST_CASES), progress=False)
    return out
