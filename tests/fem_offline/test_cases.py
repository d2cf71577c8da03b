"""`python -m fem_offline cases`: the seeded draw inside the envelope, solved, written, and resumed."""

import numpy as np

from contracts.sweep import read_cases
from fem_offline.cases import draw_cases
from fem_offline.problem import build_problem
from fem_offline.scene import load_scene
from fem_offline.solve import solve_case

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
    stamps = [f.stat().st_mtime_ns for f in files]
    files[2].unlink()
    again = cli("cases", "--scene", scene_path, "--n", 3, "--seed", 7, "--out", out, "--workers", 1)
    assert again.returncode == 0, again.stderr
    assert [f.stat().st_mtime_ns for f in files[:2]] == stamps[:2] and files[2].exists()


def test_bad_count_is_one_line_naming_the_flag(tmp_path):
    run = cli("cases", "--scene", scene_file(tmp_path, "lin", LINEAR), "--n", 0, "--out", tmp_path / "c")
    assert run.returncode == 2 and "--n must be at least 1" in run.stderr and "Traceback" not in run.stderr
