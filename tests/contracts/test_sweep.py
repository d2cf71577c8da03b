"""The sweep folder contract, written and read without any FE code."""

import json

import numpy as np
import pytest

from contracts import sweep as folder
from contracts.mesh import TetMesh, write_mesh


def _write_sweep(out, n_nodes=5, done=None):
    mesh = TetMesh(np.random.default_rng(0).normal(size=(n_nodes, 3)), np.arange(10)[None] % n_nodes,
                   np.zeros(1, np.int32), ("adipose",), {"markers": np.array([3, 1])})
    write_mesh(out / folder.MESH_FILE, mesh)
    grid = folder.Grid(displacements_mm=[1.0, 2.0], angles_deg=[-1.0, 1.0])
    record = folder.CaseRecord(newton_iterations=1, residual=0.0, min_det_f=1.0, seconds=0.1)
    files = []
    for i, a in enumerate(grid.angles_deg):
        for j, d in enumerate(grid.displacements_mm):
            name = folder.snapshot_file(i, j)
            folder.write_case(out / name, np.full((n_nodes, 3), d * a), displacement_mm=d, angle_deg=a, record=record)
            files.append(name)
    files = files[:done] if done is not None else files
    from contracts.files import sha256

    manifest = folder.SweepManifest(
        scene_name="s", scene_sha256="0" * 64, scene={"name": "s"}, mesh_sha256=sha256(out / folder.MESH_FILE),
        n_nodes=n_nodes, n_tets=1, nonlinear=True, grid=grid, envelope=grid.envelope, n_expected=4,
        n_done=len(files), snapshots=[folder.snapshot_record(out, f) for f in files])
    folder.write_manifest(out, manifest)
    return manifest


def test_round_trip(tmp_path):
    written = _write_sweep(tmp_path)
    sweep = folder.read_sweep(tmp_path)
    assert sweep.manifest == written
    assert sweep.manifest.envelope.displacement_mm == (0.0, 2.0)
    np.testing.assert_array_equal(sweep.inputs, [[1.0, -1.0], [2.0, -1.0], [1.0, 1.0], [2.0, 1.0]])
    np.testing.assert_array_equal(sweep.displacement[:, 0, 0], [-1.0, -2.0, 1.0, 2.0])
    np.testing.assert_array_equal(sweep.mesh.node_sets["markers"], [3, 1])  # marker order kept


def test_unfinished_altered_or_foreign_folders_are_refused(tmp_path):
    _write_sweep(tmp_path, done=3)
    with pytest.raises(ValueError, match="holds 3 of 4 snapshots; finish the sweep first"):
        folder.read_sweep(tmp_path)
    _write_sweep(tmp_path)
    folder.write_case(tmp_path / folder.snapshot_file(0, 0), np.zeros((5, 3)), displacement_mm=1.0, angle_deg=-1.0,
                      record=folder.CaseRecord(newton_iterations=1, residual=0.0, min_det_f=1.0, seconds=0.1))
    with pytest.raises(ValueError, match="a000_d000.npz does not match its sha256"):
        folder.read_sweep(tmp_path)
    data = json.loads((tmp_path / "manifest.json").read_text())
    (tmp_path / "manifest.json").write_text(json.dumps({**data, "format_version": 1}))
    with pytest.raises(ValueError, match="sweep format 1, this code reads 2"):
        folder.read_sweep(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({**data, "n_expected": "many"}))
    with pytest.raises(ValueError, match="n_expected"):
        folder.read_sweep(tmp_path)
