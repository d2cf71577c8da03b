"""CLI contracts: what `solve` writes, one-line errors with exit code 2, a saved mesh reused or refused."""

import numpy as np
import pytest

from fem_offline.fe.solve import solve_case

from .cli_helpers import cli, scene_file
from .conftest import SCENES


def test_solve_writes_positions_displacement_and_stats(tmp_path, tiny_problem):
    out = tmp_path / "case.npz"
    run = cli("solve", "--scene", SCENES / "tiny.toml", "--displacement-mm", 1.0, "--angle-deg", 3, "--out", out)
    assert run.returncode == 0, run.stderr
    with np.load(out) as z:
        np.testing.assert_allclose(z["reference_positions"], tiny_problem.mesh.nodes)
        assert z["displacement"].shape == tiny_problem.mesh.nodes.shape
        assert z["newton_iterations"] > 0 and z["residual"] <= 1e-6 and z["min_det_f"] > 0
        expected, _ = solve_case(tiny_problem, 1.0, 3.0)
        np.testing.assert_allclose(z["displacement"], expected, atol=1e-9)
        # det F between the solver's points too (the 11 probe points per tet), as a sweep's snapshots record it
        from fem_offline.fe.validity import probe

        assert float(z["min_det_f_probe"]) == pytest.approx(probe(tiny_problem).min_jacobian(z["displacement"].ravel()),
                                                           rel=1e-9)
        assert 0 < z["min_det_f_probe"] < 1


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--displacement-mm", "nan", "--angle-deg", "0", "--out", "x.npz"], "--displacement-mm must be finite"),
        (["--displacement-mm", "1", "--angle-deg", "0", "--out", "x.txt"], "--out: must end in .npz"),
        (["--displacement-mm", "1", "--angle-deg", "abc", "--out", "x.npz"], "--angle-deg must be a number"),
    ],
)
def test_bad_arguments_get_one_clear_line(args, message, tmp_path):
    run = cli("solve", "--scene", SCENES / "tiny.toml", *args)
    assert run.returncode == 2
    assert message in run.stderr and "Traceback" not in run.stderr


def test_bad_scene_gets_one_line_naming_the_field(tmp_path):
    scene = scene_file(tmp_path, "bad", "[guide]\npatch_radius_mm = -3\n")
    run = cli("sweep", "--scene", scene, "--out", tmp_path / "o")
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "guide.patch_radius_mm" in run.stderr and len(run.stderr.strip().splitlines()) == 1
    run = cli("sweep", "--scene", tmp_path / "missing.toml", "--out", tmp_path / "o")
    assert run.returncode == 2 and "no such scene file" in run.stderr


def test_solve_reuses_a_saved_mesh_and_rejects_a_foreign_one(tmp_path, tiny_mesh):
    from fem_offline.geometry.mesh import TetMesh, save

    path = save(tiny_mesh, tmp_path / "mesh.vtu")
    out = tmp_path / "case.npz"
    run = cli("solve", "--scene", SCENES / "tiny.toml", "--mesh", path, "--displacement-mm", 0.5, "--angle-deg", 0,
              "--out", out)
    assert run.returncode == 0, run.stderr
    np.testing.assert_array_equal(np.load(out)["reference_positions"], tiny_mesh.nodes)
    renamed = TetMesh(tiny_mesh.nodes, tiny_mesh.tets, tiny_mesh.tissue, ("liver",) + tiny_mesh.tissue_names[1:])
    foreign = save(renamed, tmp_path / "foreign.vtu")
    run = cli("solve", "--scene", SCENES / "tiny.toml", "--mesh", foreign, "--displacement-mm", 0.5, "--angle-deg", 0,
              "--out", out)
    assert run.returncode == 2 and "liver" in run.stderr and "Traceback" not in run.stderr
