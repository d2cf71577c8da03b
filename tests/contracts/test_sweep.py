"""The sweep folder contract, written and read without any FE code."""

import json

import numpy as np
import pytest

from contracts import sweep as folder
from contracts.mesh import TetMesh, write_mesh
from contracts.scene import PHANTOM_TISSUES, Scene, Tissue

# a scene of the phantom's tissues, every other field at its default
SCENE = Scene(name="s", tissues={t: Tissue(youngs_kpa=10.0, bone=t in ("pubic_bone", "spine"))
                                 for t in PHANTOM_TISSUES})


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
        scene_name="s", scene_sha256=SCENE.sha256(), scene=SCENE, mesh_sha256=sha256(out / folder.MESH_FILE),
        n_nodes=n_nodes, n_tets=1, nonlinear=True, grid=grid, envelope=grid.envelope, n_expected=4,
        n_done=len(files), snapshots=[folder.snapshot_record(out, f) for f in files])
    folder.write_manifest(out, manifest)
    return manifest


def test_round_trip(tmp_path):
    written = _write_sweep(tmp_path)
    sweep = folder.read_sweep(tmp_path)
    assert sweep.manifest == written
    assert sweep.manifest.scene == SCENE and sweep.manifest.scene.sha256() == written.scene_sha256  # typed, whole
    assert json.loads((tmp_path / folder.MANIFEST).read_text())["scene"] == SCENE.model_dump(mode="json")
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
    with pytest.raises(ValueError, match="sweep format 1, this code reads 2 and 3"):
        folder.read_sweep(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({**data, "n_expected": "many"}))
    with pytest.raises(ValueError, match="n_expected"):
        folder.read_sweep(tmp_path)


def test_validity_lists_inverted_snapshots_and_where_every_angle_is_valid(tmp_path):
    """Grid 1, 2 mm x -1, 1 deg: one inverted snapshot at (2 mm, 1 deg) and a NaN at (2 mm, -1 deg)."""
    manifest = _write_sweep(tmp_path)
    rows = [r.model_copy(update={"min_det_f": {(2.0, 1.0): -0.1, (2.0, -1.0): float("nan")}.get(
        (r.displacement_mm, r.angle_deg), r.min_det_f)}) for r in manifest.snapshots]
    v = folder.validity_of(manifest.grid, rows)
    assert v.inverted == ["snapshots/a000_d001.npz", "snapshots/a001_d001.npz"] and v.n_inverted == 2
    assert v.first_inverted_mm == [2.0, 2.0] and v.valid_up_to_mm == 1.0
    valid = folder.validity_of(manifest.grid, [r for r in rows if r.displacement_mm == 1.0])
    assert valid.n_inverted == 0 and valid.first_inverted_mm == [None, None] and valid.valid_up_to_mm == 2.0
    assert folder.validity_of(manifest.grid, [rows[3]]).valid_up_to_mm == 1.0  # only the inverted one is on disk yet
    assert folder.valid_up_to_mm([1.0, 2.0], [1.0]) == 0.0  # not even the first displacement


def test_a_snapshot_inverted_only_between_the_quadrature_points_counts_as_inverted(tmp_path):
    """min_det_f > 0 at the solver's points but min_det_f_probe <= 0 (or NaN) at the probe points: inverted,
    and validity's min det F is the lower of the two."""
    manifest = _write_sweep(tmp_path)
    probes = {(2.0, 1.0): -0.2, (2.0, -1.0): float("nan"), (1.0, 1.0): 0.4}
    rows = [r.model_copy(update={"min_det_f_probe": probes.get((r.displacement_mm, r.angle_deg), 0.9)})
            for r in manifest.snapshots]
    assert all(r.min_det_f == 1.0 for r in rows)
    v = folder.validity_of(manifest.grid, rows)
    assert v.inverted == ["snapshots/a000_d001.npz", "snapshots/a001_d001.npz"] and v.n_inverted == 2
    assert v.first_inverted_mm == [2.0, 2.0] and v.valid_up_to_mm == 1.0 and v.n_unprobed == 0
    finite = [r for r in rows if not np.isnan(r.min_det_f_probe)]
    assert folder.validity_of(manifest.grid, finite).min_det_f == -0.2
    assert folder.validity_of(manifest.grid, rows[:1]).min_det_f == 0.9  # the probe, lower than min_det_f 1.0


def test_the_probe_value_round_trips_and_is_left_out_when_not_measured(tmp_path):
    record = folder.CaseRecord(newton_iterations=1, residual=0.0, min_det_f=0.8, seconds=0.1, min_det_f_probe=-0.3)
    folder.write_case(tmp_path / "a.npz", np.zeros((5, 3)), displacement_mm=1.0, angle_deg=0.0, record=record)
    folder.write_case(tmp_path / "b.npz", np.zeros((5, 3)), displacement_mm=1.0, angle_deg=0.0,
                      record=record.model_copy(update={"min_det_f_probe": None}))
    a, b = folder.snapshot_record(tmp_path, "a.npz"), folder.snapshot_record(tmp_path, "b.npz")
    assert (a.min_det_f, a.min_det_f_probe, a.lowest_det_f) == (0.8, -0.3, -0.3)
    assert (b.min_det_f_probe, b.lowest_det_f) == (None, 0.8)
    with np.load(tmp_path / "b.npz") as z:  # nothing to unpickle: an absent value is an absent key
        assert "min_det_f_probe" not in z.files


def test_a_format_2_folder_still_reads(tmp_path):
    """Written before min_det_f_probe (format 2: no probe in the files, the manifest or its validity):
    read as it was, its snapshots unprobed; judged afresh, each counts as unprobed."""
    written = _write_sweep(tmp_path)
    data = json.loads(written.model_dump_json(exclude_none=True))
    assert "min_det_f_probe" not in json.dumps(data)
    data["format_version"] = 2
    data["validity"] = {"min_det_f": 1.0, "n_inverted": 0, "inverted": [], "first_inverted_mm": [None, None],
                        "valid_up_to_mm": 2.0}
    (tmp_path / folder.MANIFEST).write_text(json.dumps(data))
    sweep = folder.read_sweep(tmp_path)
    assert sweep.manifest.format_version == 2 and sweep.displacement.shape == (4, 5, 3)
    assert all(r.min_det_f_probe is None for r in sweep.manifest.snapshots)
    assert folder.sweep_validity(sweep.manifest).valid_up_to_mm == 2.0 and sweep.manifest.validity.n_unprobed is None
    assert folder.validity_of(sweep.manifest.grid, sweep.manifest.snapshots).n_unprobed == 4


def test_a_folder_from_before_the_check_is_judged_by_its_solver(tmp_path):
    """No `validity` (format 2 as first written): a nonlinear sweep's records were measured by Newton,
    a linear sweep's say 1.0 unmeasured and are refused."""
    manifest = _write_sweep(tmp_path)
    assert manifest.validity is None
    assert folder.sweep_validity(manifest).valid_up_to_mm == 2.0
    with pytest.raises(ValueError, match="linear sweep was written before det"):
        folder.sweep_validity(manifest.model_copy(update={"nonlinear": False}))
