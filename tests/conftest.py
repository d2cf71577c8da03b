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
    return _linear_sweep(tiny_linear_scene(), tmp_path_factory.mktemp("sweep"))


@pytest.fixture(scope="session")
def tiny_model(tiny_sweep, tmp_path_factory) -> Path:
    return _fitted(tiny_sweep, tmp_path_factory.mktemp("models") / "tiny", rank=8)


def tiny_linear_scene(**sections):
    """tiny.toml (glued) with the small-strain model on a 1 mm x 2 deg grid to 10 mm: superposable, seconds."""
    from fem_offline.scene import load_scene

    return load_scene(SCENES / "tiny.toml", effects={"geometric_nonlinearity": False},
                      sweep={"displacement_step_mm": 1.0, "displacement_max_mm": 10.0, "angle_min_deg": -10.0,
                             "angle_max_deg": 10.0, "angle_step_deg": 2.0}, **sections)


def _linear_sweep(scene, out: Path) -> Path:
    from fem_offline.sweep import run_sweep

    assert run_sweep(scene, out).n_done == 110
    return out


def _fitted(sweep: Path, out: Path, *, rank: int) -> Path:
    from training.fit import FitOptions, fit

    fit(sweep, out, FitOptions(rank=rank, max_iterations=300, test_cases=TINY_TEST_CASES), progress=False)
    return out


TINY_MATERIALS = {  # every soft tissue's stiffness as an input, around tiny.toml's (default.toml's) E
    "prostate": {"youngs_kpa_range": [50.0, 85.0], "std_percent": 20.0, "source": "test"},
    "rectal_wall": {"youngs_kpa_range": [140.0, 215.0], "std_percent": 20.0, "source": "test"},
    "adipose": {"youngs_kpa_range": [8.5, 13.5], "std_percent": 20.0, "source": "test"},
    "bladder": {"youngs_kpa_range": [80.0, 125.0], "std_percent": 20.0, "source": "test"},
}


def tiny_material_scene(**materials):
    """tiny_linear_scene with material inputs (default: TINY_MATERIALS)."""
    return tiny_linear_scene(materials=materials or TINY_MATERIALS)


@pytest.fixture(scope="session")
def tiny_material_sweep(tmp_path_factory) -> Path:
    """tiny_sweep's grid, superposed, with S_i = du/d ln E_i of the four soft tissues in every snapshot."""
    return _linear_sweep(tiny_material_scene(), tmp_path_factory.mktemp("material_sweep"))


@pytest.fixture(scope="session")
def tiny_material_model(tiny_material_sweep, tmp_path_factory) -> Path:
    """A material model on tiny_material_sweep (answers for 0..5 mm, like tiny_model)."""
    return _fitted(tiny_material_sweep, tmp_path_factory.mktemp("models") / "tiny_materials", rank=12)


# the patient box as factors of the tiny scene's nominal E (fem_offline/scenes/patient_box.toml)
FACTORS = {"prostate": (0.4, 1.6), "rectal_wall": (0.1, 1.2), "adipose": (0.5, 1.6), "bladder": (0.3, 3.0)}


def tiny_box_scene():
    from fem_offline.scene import load_scene

    base = load_scene(SCENES / "tiny.toml")
    box = {t: {"youngs_kpa_range": [base.tissues[t].youngs * a, base.tissues[t].youngs * b], "std_percent": 21.0}
           for t, (a, b) in FACTORS.items()}
    return load_scene(SCENES / "tiny.toml", effects={"geometric_nonlinearity": False},
                      sweep={"displacement_step_mm": 2.0, "displacement_max_mm": 4.0}, materials=box)


@pytest.fixture(scope="session")
def tiny_design(tmp_path_factory):
    """A linear tiny design over the patient box (16 points, S_i at 4 mm) and a held-out one (the 16 corners)."""
    from fem_offline.design import run_design

    scene, root = tiny_box_scene(), tmp_path_factory.mktemp("design")
    assert run_design(scene, root / "train", n=16, seed=0, sensitivity_every=2)["finished"] == 16
    assert run_design(scene, root / "held", n=16, seed=1, held_out=True, sensitivities=False)["finished"] == 16
    return root


@pytest.fixture(scope="session")
def design_model(tiny_design, tmp_path_factory):
    from contracts.model import FitOptions
    from training.design_fit import fit_design

    out = tmp_path_factory.mktemp("models") / "design"
    fit_design(tiny_design / "train", out, FitOptions(rank=10, sensitivity_rank=10, max_iterations=300, test_cases=()),
               held_out=tiny_design / "held", progress=False)
    return out
