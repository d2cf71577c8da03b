"""CLI and sweep contracts: outputs, one-line errors, resumability, atomic files, pool vs Dask."""

import json
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fem_offline.mesh import load as load_mesh
from fem_offline.problem import build_problem
from fem_offline.scene import load_scene
from fem_offline.solve import solve_case
from fem_offline.sweep import run_sweep

from .conftest import SCENES

ROOT = Path(__file__).resolve().parents[2]


def _cli(*args, **kw):
    return subprocess.run([sys.executable, "-m", "fem_offline", *map(str, args)], capture_output=True, text=True, cwd=ROOT, **kw)


def _scene_file(tmp_path, name, extra):
    """tiny.toml with the sections named in `extra` replaced by `extra`'s."""
    text = (SCENES / "tiny.toml").read_text()
    for header in re.findall(r"^\[\w+\]$", extra, flags=re.M):
        text = re.sub(rf"^{re.escape(header)}$.*?(?=^\[|\Z)", "", text, flags=re.M | re.S)
    path = tmp_path / f"{name}.toml"
    path.write_text(text + "\n" + extra)
    return path


LINEAR = "[effects]\ngeometric_nonlinearity = false\n"
MINI = """[sweep]
displacement_step_mm = 1.0
displacement_max_mm = 2.0
angle_min_deg = -10.0
angle_max_deg = 10.0
angle_step_deg = 20.0
"""

# Solve the scene's first path as a sweep worker does, and SIGKILL the process as soon as its first
# snapshot is on disk: a kill -9 at a known point, not at whatever moment a poll notices a file.
KILL_AFTER_FIRST_SNAPSHOT = """
import os, signal, sys
from pathlib import Path
from fem_offline import sweep
from fem_offline.scene import load_scene
from fem_offline.solve import solve_case

write = sweep.write_snapshot


def write_then_die(*args, **kw):
    write(*args, **kw)
    os.kill(os.getpid(), signal.SIGKILL)


sweep.write_snapshot = write_then_die
scene, out = load_scene(sys.argv[1]), Path(sys.argv[2])
sweep.prepare(scene, out)
sweep.run_path(scene.model_dump_json(), str(out), sweep.grid(scene)[0])
"""


def test_solve_writes_positions_displacement_and_stats(tmp_path, tiny_problem):
    out = tmp_path / "case.npz"
    run = _cli("solve", "--scene", SCENES / "tiny.toml", "--displacement-mm", 1.0, "--angle-deg", 3, "--out", out)
    assert run.returncode == 0, run.stderr
    with np.load(out) as z:
        np.testing.assert_allclose(z["reference_positions"], tiny_problem.mesh.nodes)
        assert z["displacement"].shape == tiny_problem.mesh.nodes.shape
        assert z["newton_iterations"] > 0 and z["residual"] <= 1e-6 and z["min_det_f"] > 0
        expected, _ = solve_case(tiny_problem, 1.0, 3.0)
        np.testing.assert_allclose(z["displacement"], expected, atol=1e-9)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--displacement-mm", "nan", "--angle-deg", "0", "--out", "x.npz"], "--displacement-mm must be finite"),
        (["--displacement-mm", "1", "--angle-deg", "0", "--out", "x.txt"], "--out: must end in .npz"),
        (["--displacement-mm", "1", "--angle-deg", "abc", "--out", "x.npz"], "--angle-deg must be a number"),
    ],
)
def test_bad_arguments_get_one_clear_line(args, message, tmp_path):
    run = _cli("solve", "--scene", SCENES / "tiny.toml", *args)
    assert run.returncode == 2
    assert message in run.stderr and "Traceback" not in run.stderr


def test_bad_scene_gets_one_line_naming_the_field(tmp_path):
    scene = _scene_file(tmp_path, "bad", "[guide]\npatch_radius_mm = -3\n")
    run = _cli("sweep", "--scene", scene, "--out", tmp_path / "o")
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "guide.patch_radius_mm" in run.stderr and len(run.stderr.strip().splitlines()) == 1
    run = _cli("sweep", "--scene", tmp_path / "missing.toml", "--out", tmp_path / "o")
    assert run.returncode == 2 and "no such scene file" in run.stderr


def test_linear_sweep_superposes_and_resumes(tmp_path):
    scene = load_scene(_scene_file(tmp_path, "lin", LINEAR))
    out = tmp_path / "sweep"
    manifest = run_sweep(scene, out)
    assert manifest["n_done"] == manifest["n_expected"] == 12 and not manifest["errors"]
    snap = out / "snapshots" / "a002_d001.npz"  # +10 deg, 5 mm
    with np.load(snap) as z:
        # A direct solve on the sweep's own mesh (not a fresh gmsh run, which CI once saw differ).
        expected, _ = solve_case(build_problem(scene, load_mesh(out / "mesh.vtu")), 5.0, 10.0)
        np.testing.assert_allclose(z["displacement"], expected, atol=1e-10)
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "snapshots").iterdir()}
    snap.unlink()
    manifest = run_sweep(scene, out)
    assert manifest["n_done"] == 12 and snap.exists()
    assert all((out / "snapshots" / n).stat().st_mtime_ns == t for n, t in stamps.items() if n != snap.name)
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]


def test_sweep_refuses_a_folder_of_another_scene(tmp_path):
    out = tmp_path / "sweep"
    run_sweep(load_scene(_scene_file(tmp_path, "lin", LINEAR)), out)
    other = _scene_file(tmp_path, "lin2", LINEAR.replace("false", "false\ngravity = true"))
    run = _cli("sweep", "--scene", other, "--out", out)
    assert run.returncode == 2 and "another scene" in run.stderr


def test_killed_sweep_resumes_to_the_same_answer(tmp_path, tiny_problem):
    """Kill -9 right after the first snapshot: only whole files on disk; the rerun finishes the path."""
    scene = _scene_file(tmp_path, "one", MINI.replace("angle_min_deg = -10.0", "angle_min_deg = 10.0").replace("displacement_max_mm = 2.0", "displacement_max_mm = 3.0"))
    out = tmp_path / "sweep"
    killed = subprocess.run([sys.executable, "-c", KILL_AFTER_FIRST_SNAPSHOT, str(scene), str(out)], cwd=ROOT, capture_output=True, text=True)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    assert [p.name for p in (out / "snapshots").iterdir()] == ["a000_d000.npz"]
    np.load(out / "snapshots" / "a000_d000.npz")["displacement"]  # whole, readable
    run = _cli("sweep", "--scene", scene, "--out", out, "--workers", "1")
    assert run.returncode == 0, run.stderr
    with np.load(out / "snapshots" / "a000_d002.npz") as z:
        expected, _ = solve_case(tiny_problem, 3.0, 10.0, step_mm=0.5)
        np.testing.assert_allclose(z["displacement"], expected, atol=1e-5)
    assert json.loads((out / "manifest.json").read_text())["n_done"] == 3


def test_dask_cluster_matches_local_pool(tmp_path):
    from distributed import LocalCluster

    scene = load_scene(_scene_file(tmp_path, "mini", MINI))
    local = run_sweep(scene, tmp_path / "local", workers=2)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        remote = run_sweep(scene, tmp_path / "dask", scheduler=cluster.scheduler_address)
    assert local["n_done"] == remote["n_done"] == 4
    for row in local["snapshots"]:
        a = np.load(tmp_path / "local" / row["file"])["displacement"]
        b = np.load(tmp_path / "dask" / row["file"])["displacement"]
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_solve_reuses_a_saved_mesh_and_rejects_a_foreign_one(tmp_path, tiny_mesh):
    from fem_offline.mesh import TetMesh, save

    path = save(tiny_mesh, tmp_path / "mesh.vtu")
    out = tmp_path / "case.npz"
    run = _cli("solve", "--scene", SCENES / "tiny.toml", "--mesh", path, "--displacement-mm", 0.5, "--angle-deg", 0, "--out", out)
    assert run.returncode == 0, run.stderr
    np.testing.assert_array_equal(np.load(out)["reference_positions"], tiny_mesh.nodes)
    renamed = TetMesh(tiny_mesh.nodes, tiny_mesh.tets, tiny_mesh.tissue, ("liver",) + tiny_mesh.tissue_names[1:])
    foreign = save(renamed, tmp_path / "foreign.vtu")
    run = _cli("solve", "--scene", SCENES / "tiny.toml", "--mesh", foreign, "--displacement-mm", 0.5, "--angle-deg", 0, "--out", out)
    assert run.returncode == 2 and "liver" in run.stderr and "Traceback" not in run.stderr


def test_symmetric_sweep_solves_half_and_reflects_the_rest(tmp_path, tiny_problem):
    """Angles -10 and +10: only +10 is solved; the -10 snapshots are its reflections and equal a
    direct nonlinear solve at -10 deg (the mesh and the guide are mirror-symmetric)."""
    scene = load_scene(_scene_file(tmp_path, "mini", MINI))
    manifest = run_sweep(scene, tmp_path / "sweep")
    assert manifest["n_done"] == 4 and manifest["n_mirrored"] == 2 and not manifest["errors"]
    with np.load(tmp_path / "sweep" / "snapshots" / "a000_d001.npz") as z:  # -10 deg, 2 mm
        assert str(z["mirrored_from"]) == "a001_d001.npz" and float(z["angle_deg"]) == -10.0
        direct, _ = solve_case(tiny_problem, 2.0, -10.0, step_mm=1.0)
        np.testing.assert_allclose(z["displacement"], direct, atol=1e-6 * np.abs(direct).max())
