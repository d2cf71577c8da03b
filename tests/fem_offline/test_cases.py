"""`python -m fem_offline cases`: the seeded draw inside the envelope, solved, written, and resumed."""

import numpy as np
import pytest

from contracts.sweep import read_cases
from fem_offline.cases import draw_cases
from fem_offline.fe.problem import build_problem
from fem_offline.scene import load_scene
from fem_offline.fe.solve import solve_case

from .cli_helpers import LINEAR, cli, scene_file


def test_cases_are_the_seeded_draw_solved_on_their_own_mesh_and_resume(tmp_path):
    scene_path = scene_file(tmp_path, "lin", LINEAR)
    scene, out = load_scene(scene_path), tmp_path / "cases"
    run = cli("cases", "--scene", scene_path, "--n", 3, "--seed", 7, "--out", out, "--workers", 1)
    assert run.returncode == 0, run.stderr
    files = sorted(out.glob("offgrid_*.npz"))
    inputs, displacement = read_cases(files)
    drawn = draw_cases(scene, 3, 7)
    np.testing.assert_array_equal(inputs, drawn)
    sw = scene.sweep
    assert all(sw.displacement_step_mm <= d <= sw.displacement_max_mm and sw.angle_min_deg <= a <= sw.angle_max_deg
               for d, a in drawn)
    from contracts.mesh import read_mesh

    problem = build_problem(scene, read_mesh(out / "mesh.npz"))
    expected, _ = solve_case(problem, *drawn[1])
    np.testing.assert_allclose(displacement[1], expected, atol=1e-10)
    from fem_offline.fe.validity import probe

    probed = probe(problem)  # each case's det F between the solver's points, as a sweep's snapshots record it
    for f, u in zip(files, displacement):
        with np.load(f) as z:
            assert float(z["min_det_f_probe"]) == pytest.approx(probed.min_jacobian(u.ravel()), rel=1e-9)
    stamps = [f.stat().st_mtime_ns for f in files]
    files[2].unlink()
    again = cli("cases", "--scene", scene_path, "--n", 3, "--seed", 7, "--out", out, "--workers", 1)
    assert again.returncode == 0, again.stderr
    assert [f.stat().st_mtime_ns for f in files[:2]] == stamps[:2] and files[2].exists()


def test_bad_count_is_one_line_naming_the_flag(tmp_path):
    run = cli("cases", "--scene", scene_file(tmp_path, "lin", LINEAR), "--n", 0, "--out", tmp_path / "c")
    assert run.returncode == 2 and "--n must be at least 1" in run.stderr and "Traceback" not in run.stderr


CONTACT_GRID = """[effects]
guide_contact = true
[sweep]
displacement_step_mm = 0.5
displacement_max_mm = 1.0
angle_min_deg = 0.0
angle_max_deg = 10.0
angle_step_deg = 10.0
"""


def test_a_case_started_from_the_sweep_reaches_the_equilibrium_of_the_path_from_rest(tmp_path):
    """Hyperelastic tissue and frictionless contact are conservative: the equilibrium at (0.75 mm, 4 deg)
    does not depend on the start. Newton started there from the bilinear blend of the 4 snapshots
    around it meets the same tolerances as the path from rest, with less work, and lands on its answer
    within what the contact tolerance leaves open."""
    from contracts.mesh import read_mesh
    from fem_offline.cases import _solve, grid_start
    from fem_offline.sweep import run_sweep

    scene = load_scene(scene_file(tmp_path, "contact", CONTACT_GRID))
    manifest = run_sweep(scene, tmp_path / "sweep", workers=1)
    assert manifest.n_done == 4 and not manifest.errors
    problem = build_problem(scene, read_mesh(tmp_path / "sweep" / "mesh.npz"))
    start = grid_start(tmp_path / "sweep", manifest.grid, 0.75, 4.0)
    with np.load(tmp_path / "sweep" / "snapshots" / "a000_d000.npz") as a, \
            np.load(tmp_path / "sweep" / "snapshots" / "a001_d001.npz") as b:
        corners = (a["displacement"].ravel(), b["displacement"].ravel())
    assert np.abs(start).max() > 0 and not np.allclose(start, corners[0]) and not np.allclose(start, corners[1])
    warm, warm_stats, how = _solve(problem, 0.75, 4.0, str(tmp_path / "sweep"))
    rest, rest_stats = solve_case(problem, 0.75, 4.0)
    assert how == "sweep"
    for stats in (warm_stats, rest_stats):
        assert stats.residual <= scene.solver.rtol and stats.penetration_mm <= scene.guide.contact_tol_mm
    assert warm_stats.iterations < rest_stats.iterations
    assert np.linalg.norm(warm - rest, axis=1).max() < 0.01 * np.linalg.norm(rest, axis=1).max()


def test_cases_refuse_a_sweep_of_other_physics(tmp_path):
    from fem_offline.sweep import run_sweep

    run_sweep(load_scene(scene_file(tmp_path, "lin", LINEAR)), tmp_path / "sweep")
    run = cli("cases", "--scene", scene_file(tmp_path, "contact", CONTACT_GRID), "--n", 1, "--out", tmp_path / "c",
              "--sweep", tmp_path / "sweep", "--mesh", tmp_path / "sweep" / "mesh.npz")
    assert run.returncode == 2 and "--sweep" in run.stderr and "another scene" in run.stderr
    assert "Traceback" not in run.stderr and not list((tmp_path / "c").glob("offgrid_*.npz"))
