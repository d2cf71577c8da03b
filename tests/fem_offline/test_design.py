"""fem_offline design: the points (canonical ratios, corners first when held out), the folder contract (resume,
refusal of another design), the CLI's errors, and a real Dask cluster (a `dask scheduler` and two `dask worker`
processes) giving the local pool's snapshots."""

import itertools
import json
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from contracts.design import read_design, read_design_file
from contracts.materials import ratio_point
from fem_offline.design import log_box, make_design
from fem_offline.scene import load_scene

from .cli_helpers import LINEAR, MATERIALS, ROOT, cli, scene_file

ONE_PUSH = ("[sweep]\ndisplacement_step_mm = 2.0\ndisplacement_max_mm = 2.0\nangle_min_deg = -10.0\n"
            "angle_max_deg = 10.0\n")


@pytest.fixture
def box_scene(tmp_path):
    return scene_file(tmp_path, "box", LINEAR + ONE_PUSH + MATERIALS)


def test_design_points_are_canonical_and_inside_the_box(box_scene):
    scene = load_scene(box_scene)
    box = log_box(scene)
    lo, hi = [b[0] for b in box.values()], [b[1] for b in box.values()]
    design = make_design(scene, n=16, seed=0, sensitivities=True, held_out=False)
    assert len(design.points) == 16 and design.sensitivity_every == 4
    for p in design.points:
        theta = [p.theta[t] for t in box]
        assert 0 <= p.angle_deg <= 10
        assert all(lo_ - 1e-9 <= t <= hi_ + 1e-9 for t, lo_, hi_ in zip(theta, lo, hi))
        np.testing.assert_allclose(ratio_point(theta, lo, hi, list(box)), theta, atol=1e-8)  # already canonical


def test_a_held_out_design_starts_with_every_corner_at_the_largest_angle(box_scene):
    scene = load_scene(box_scene)
    box = log_box(scene)
    design = make_design(scene, n=20, seed=1, sensitivities=False, held_out=True)
    corners = {tuple(np.round(ratio_point(c, [b[0] for b in box.values()], [b[1] for b in box.values()], list(box)), 6))
               for c in itertools.product(*box.values())}
    first = {tuple(np.round([p.theta[t] for t in box], 6)) for p in design.points[:16]}
    assert first == corners and all(p.angle_deg == 10.0 for p in design.points)


def test_a_design_resumes_and_refuses_another(box_scene, tmp_path):
    out = tmp_path / "d"
    done = cli("design", "--scene", box_scene, "--out", out, "--n", "2", "--workers", "1")
    assert done.returncode == 0, done.stderr
    assert "2/2 points finished" in done.stdout
    data = read_design(out)
    assert len(data.inputs) == 4 and data.inputs.shape[1] == 6 and not data.unfinished  # 2 points x (-beta, beta)
    for k in range(2):  # each point's path at -beta is its path at +beta (the mirror)
        angles = data.inputs[data.point == k, 1]
        assert sorted(angles) == sorted(-angles) and angles.max() > 0
    mirrored = [f for f in out.glob("p*/snapshots/*.npz") if "mirrored_from" in np.load(f).files]
    assert len(mirrored) == 2
    for f in mirrored:  # as a run stopped before reflecting them left them
        f.unlink()
    again = cli("design", "--scene", box_scene, "--out", out, "--n", "2", "--workers", "1")
    assert again.returncode == 0 and "4/4 snapshots" in again.stdout, again.stdout
    assert all(f.exists() for f in mirrored)  # reflected on resume, nothing solved again
    other = cli("design", "--scene", box_scene, "--out", out, "--n", "3")
    assert other.returncode == 2 and "holds another design" in other.stderr


def test_a_finer_push_step_gives_more_snapshots_and_the_same_equilibrium(box_scene, tmp_path):
    """--push-step is recorded in design.json and sets every path's step; the equilibrium at the largest push does
    not depend on the path that reached it."""
    coarse, fine = tmp_path / "coarse", tmp_path / "fine"
    assert cli("design", "--scene", box_scene, "--out", coarse, "--n", "1", "--workers", "1").returncode == 0
    done = cli("design", "--scene", box_scene, "--out", fine, "--n", "1", "--workers", "1", "--push-step", "1")
    assert done.returncode == 0, done.stderr
    assert read_design_file(fine).displacement_step_mm == 1.0 and read_design_file(coarse).displacement_step_mm is None
    a, b = read_design(coarse), read_design(fine)
    assert sorted(set(b.inputs[:, 0])) == [1.0, 2.0] and len(b.inputs) == 2 * len(a.inputs)

    def last(d, angle):
        return d.displacement[(d.inputs[:, 0] == 2.0) & (d.inputs[:, 1] == angle)][0]

    for angle in set(a.inputs[:, 1]):
        np.testing.assert_allclose(last(b, angle), last(a, angle), atol=1e-6 * np.abs(last(a, angle)).max())


def test_the_design_cli_names_the_bad_field(box_scene, tmp_path):
    plain = scene_file(tmp_path, "plain", LINEAR)
    assert "[materials]" in cli("design", "--scene", plain, "--out", tmp_path / "x").stderr
    bad = cli("design", "--scene", box_scene, "--out", tmp_path / "y", "--scheduler", "localhost:1")
    assert bad.returncode == 2 and "--scheduler" in bad.stderr
    nomesh = cli("design", "--scene", box_scene, "--out", tmp_path / "z", "--mesh", tmp_path / "none.npz")
    assert nomesh.returncode == 2 and "--mesh" in nomesh.stderr
    step = cli("design", "--scene", box_scene, "--out", tmp_path / "w", "--push-step", "0.3")
    assert step.returncode == 2 and "--push-step" in step.stderr and "does not divide" in step.stderr


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow  # a scheduler and two workers start as their own processes
def test_a_design_on_a_dask_cluster_of_its_own_processes_matches_the_local_pool(box_scene, tmp_path):
    """`dask scheduler` and two `dask worker` processes, then `fem_offline design --scheduler`: the same snapshots
    as the local pool's on the same mesh."""
    local = cli("design", "--scene", box_scene, "--out", tmp_path / "local", "--n", "2", "--workers", "2")
    assert local.returncode == 0, local.stderr
    address = f"tcp://127.0.0.1:{_free_port()}"
    dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    procs = [subprocess.Popen([*dask, "--host", "127.0.0.1", "--port", address.rsplit(":", 1)[1],
                               "--dashboard-address", ":0"], cwd=ROOT, stderr=subprocess.DEVNULL)]
    try:
        time.sleep(3)
        procs += [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
                                    "--nworkers", "1", "--dashboard-address", ":0"], cwd=ROOT,
                                   stderr=subprocess.DEVNULL) for _ in range(2)]
        (tmp_path / "dask").mkdir()
        (tmp_path / "dask" / "mesh.npz").write_bytes((tmp_path / "local" / "mesh.npz").read_bytes())
        remote = cli("design", "--scene", box_scene, "--out", tmp_path / "dask", "--n", "2", "--scheduler", address,
                     timeout=600)
        assert remote.returncode == 0, remote.stderr
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.wait(timeout=30)
    a, b = read_design(tmp_path / "local"), read_design(tmp_path / "dask")
    assert read_design_file(tmp_path / "local") == read_design_file(tmp_path / "dask")
    np.testing.assert_array_equal(a.inputs, b.inputs)
    np.testing.assert_allclose(a.displacement, b.displacement, atol=1e-12)
    assert json.loads((tmp_path / "dask" / "run.json").read_text())["finished"] == 2
