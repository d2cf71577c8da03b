"""`python -m training fit` end to end on a tiny sweep: the folder, its manifest, hashes and atomic writes."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from service.model import ModelError, Predictor, read_model_folder
from fem_offline.scene import parse_scene
from training.snapshots import read_sweep


def test_folder_holds_what_the_manifest_promises(tiny_model, tiny_sweep, tiny_test_cases):
    m = json.loads((tiny_model / "manifest.json").read_text())
    sweep = read_sweep(tiny_sweep)
    assert m["mesh"]["n_nodes"] == len(sweep.mesh.nodes) and m["mesh"]["n_tets"] == len(sweep.mesh.tets)
    assert m["pca"]["rank"] == 8 and 0.999 < m["pca"]["energy"] <= 1.0
    assert m["scene"]["sha256"] == sweep.manifest.scene_sha256
    assert parse_scene(m["scene"]["spec"]).sha256() == m["scene"]["sha256"]  # the full scene, as solved
    assert m["fit"] == {"rank": 8, "sensitivity_rank": 32, "width": 60, "depth": 1, "max_iterations": 300, "seed": 0,
                        "test_cases": [list(c) for c in tiny_test_cases]}
    # the linear sweep inverts elements beyond valid_up_to_mm: the model is cut there (test_inversion_stability.py)
    cut_mm = sweep.manifest.validity.valid_up_to_mm
    assert m["envelope"] == {"displacement_mm": [0.0, cut_mm], "angle_deg": [-10.0, 10.0]}
    assert (m["network"]["n_train"] == 11 * int(cut_mm) - 2
            and set(m["files"]) == {"model.onnx", "mesh.npz", "report.md"})
    assert {"prostate", "prostate_surface", "markers", "guide_patch", "adipose"} <= set(m["regions"])
    assert m["regions"]["markers"] == 8
    rows = m["metrics"]["table3"]
    assert [(r["displacement_mm"], r["angle_deg"]) for r in rows] == list(tiny_test_cases)
    assert m["metrics"]["onnx_vs_float64_max_abs_mm"] < 1e-4


def test_held_out_metrics_are_recomputed_from_the_shipped_model(tiny_model, tiny_sweep):
    """The manifest's e_NN is what the exported ONNX model gives on the left-out snapshots."""
    folder = read_model_folder(tiny_model)
    predictor = Predictor(folder)
    sweep = read_sweep(tiny_sweep)
    markers = sweep.mesh.node_sets["markers"]
    at_markers = 0.0
    for row in folder.manifest.metrics.table3:
        i = np.flatnonzero((sweep.inputs[:, 0] == row.displacement_mm) & (sweep.inputs[:, 1] == row.angle_deg))[0]
        err = np.linalg.norm(predictor.displacement(*sweep.inputs[i]) - sweep.displacement[i], axis=1).max()
        assert err == pytest.approx(row.e_nn_mm, rel=1e-3, abs=1e-7)
        assert err < 0.01 * np.abs(sweep.displacement[i]).max()  # linear data: the fit is tight
        at_markers = max(at_markers, np.linalg.norm(predictor.displacement(*sweep.inputs[i])[markers]
                                                    - sweep.displacement[i][markers], axis=1).max())
    acc = folder.manifest.accuracy.regions["markers"]
    assert acc.surrogate_mm == pytest.approx(at_markers, rel=1e-5, abs=1e-9)
    assert acc.fe_discretisation_mm is None and acc.end_to_end_mm is None  # no study given: said, not guessed
    assert "not measured" in folder.manifest.accuracy.reference


def test_zero_load_gives_exactly_zero_displacement(tiny_model):
    predictor = Predictor(read_model_folder(tiny_model))
    for angle in (-10.0, 0.0, 10.0):
        assert np.all(predictor.displacement(0.0, angle) == 0.0)


def test_mesh_surfaces_are_closed_and_outward(tiny_model):
    """Each tissue's boundary triangles form a closed surface enclosing positive volume (divergence theorem)."""
    folder = read_model_folder(tiny_model)
    for name, tri in folder.surfaces.items():
        p = folder.nodes[tri]
        volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6
        edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        assert volume > 0, name
        assert (counts % 2 == 0).all(), name  # every edge shared by an even number of triangles


def test_corrupt_or_incomplete_folder_is_refused(tiny_model, tmp_path):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(tiny_model, bad)
    with open(bad / "model.onnx", "r+b") as f:
        f.seek(100)
        f.write(b"\x00\x01\x02")
    with pytest.raises(ModelError, match="model.onnx does not match its sha256"):
        read_model_folder(bad)
    shutil.copy(tiny_model / "model.onnx", bad / "model.onnx")
    read_model_folder(bad)
    (bad / "mesh.npz").unlink()
    with pytest.raises(ModelError, match="mesh.npz is listed in the manifest but missing"):
        read_model_folder(bad)
    with pytest.raises(ModelError, match="no manifest.json"):
        read_model_folder(tmp_path)


def test_failed_export_leaves_the_previous_model_intact(tiny_model, tiny_sweep, tiny_test_cases, tmp_path, monkeypatch):
    import shutil

    import contracts.model as folder_mod
    from training.fit import FitOptions, fit

    out = tmp_path / "m"
    shutil.copytree(tiny_model, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def crash(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(folder_mod, "_write_mesh", crash)
    with pytest.raises(OSError, match="disk full"):
        fit(tiny_sweep, out, FitOptions(rank=4, max_iterations=20, test_cases=tiny_test_cases), progress=False)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m"]  # no temporary folder left behind
    read_model_folder(out)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "training", *map(str, args)], capture_output=True, text=True)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--rank", "0"], "--rank must be at least 1"),
        (["--rank", "500", "--test-case", "5/-2"],
         "are left to train on once 1 are held out; 500 modes need at least 501"),
        (["--test-case", "7.75"], "--test-case: expected DISPLACEMENT_MM/ANGLE_DEG"),
        (["--test-case", "7.7/-5"], "--test-case 7.7/-5.0: not a snapshot of this sweep"),
    ],
)
def test_bad_arguments_get_one_clear_line(args, message, tiny_sweep, tmp_path):
    run = _cli("fit", "--snapshots", tiny_sweep, "--out", tmp_path / "m", *args)
    assert run.returncode == 2 and message in run.stderr and "Traceback" not in run.stderr
    assert not (tmp_path / "m").exists()


def test_unfinished_sweep_is_refused(tiny_sweep, tmp_path):
    import shutil

    partial = tmp_path / "partial"
    shutil.copytree(tiny_sweep, partial)
    next((partial / "snapshots").iterdir()).unlink()
    run = _cli("fit", "--snapshots", partial, "--out", tmp_path / "m")
    assert run.returncode == 2 and "holds 109 of 110 snapshots" in run.stderr


def test_cli_writes_the_model_its_flags_ask_for_and_prints_its_metrics(tiny_sweep, tmp_path):
    run = _cli("fit", "--snapshots", tiny_sweep, "--out", tmp_path / "m", "--rank", "4", "--width", "12",
               "--iterations", "50", "--seed", "3", "--test-case", "5/-2")
    assert run.returncode == 0, run.stderr
    m = read_model_folder(tmp_path / "m").manifest
    assert m.fit.model_dump() == {"rank": 4, "sensitivity_rank": 32, "width": 12, "depth": 1, "max_iterations": 50,
                                  "seed": 3, "test_cases": ((5.0, -2.0),)}
    assert m.pca.rank == 4 and m.network.width == 12 and m.network.iterations <= 50
    assert [(r.displacement_mm, r.angle_deg) for r in m.metrics.table3] == [(5.0, -2.0)]
    e_nn = float(re.search(r"e_NN ([0-9.]+) mm", run.stdout).group(1))  # the printed line states the stored metric
    assert e_nn == pytest.approx(m.metrics.table3_summary.e_nn_mm, abs=5e-5)


def test_fe_band_is_the_studys_band_of_the_model_mesh_level(tmp_path):
    """--fe-error picks the GCI band for the finest level, the distance to the finest plus that band for the
    one before, and refuses any other mesh."""
    from types import SimpleNamespace

    from training.fit import fe_discretisation

    def zone(fine, medium):
        return {"gci_mm": {"max": fine}, "gci_medium_mm": {"max": 9.0}, "bound_medium_mm": {"max": medium}}

    case = {"markers": [{"gci_vector_mm": 0.1, "gci_vector_medium_mm": 9.0, "bound_medium_mm": 0.3},
                        {"gci_vector_mm": 0.05, "gci_vector_medium_mm": 9.0, "bound_medium_mm": 0.4}],
            "surface_near_tip": zone(0.7, 1.5), "surface_rest": zone(0.2, 0.6), "all_nodes": zone(0.9, 2.0)}
    levels = [{"n_tets": n, "n_nodes": 2 * n} for n in (100, 200, 400)]
    study = tmp_path / "study.json"
    study.write_text(json.dumps({"analysis": {"levels": levels, "ratio": 1.3, "cases": {"10 mm, 0 deg": case}}}))
    mesh = lambda n: SimpleNamespace(tets=np.zeros((n, 10)), nodes=np.zeros((2 * n, 3)))  # noqa: E731
    fine, text = fe_discretisation(study, mesh(400))
    assert fine == {"markers": 0.1, "prostate_surface": 0.7, "all_nodes": 0.9} and "fine level" in text
    medium, text = fe_discretisation(study, mesh(200))
    assert medium == {"markers": 0.4, "prostate_surface": 1.5, "all_nodes": 2.0} and "medium level" in text
    with pytest.raises(ValueError, match="neither of"):
        fe_discretisation(study, mesh(100))


MEASURED_SURROGATE = {"markers": 0.004, "prostate_surface": 0.006, "all_nodes": 0.05}  # of the model the study measured


def _model_vs_converged(model, tmp_path, gaps, n_tets=None, measured=MEASURED_SURROGATE):
    folder = read_model_folder(model)
    data = {"kind": "model_vs_converged", "model": str(model), "element": "taylor_hood",
            "levels": [{"scale": s, "n_tets": n, "n_nodes": 2 * n}
                       for s, n in ((1.69, 100), (1.3, 200), (1.0, 400), (0.769, 800))],
            "model_mesh": {"n_tets": n_tets or len(folder.mesh.tets), "n_nodes": len(folder.mesh.nodes)},
            "cases": {"10 mm, 0 deg": {"scales": [1.3, 1.0, 0.769]}, "10 mm, 10 deg": {"scales": [1.69, 1.3, 1.0]}},
            "max_over_cases": gaps, **({"model_surrogate_mm": measured} if measured else {})}
    path = tmp_path / "fe_error.json"
    path.write_text(json.dumps(data))
    return path


def test_restamp_changes_only_the_accuracy_and_keeps_the_folder_valid(tiny_model, tmp_path):
    """`training restamp` stamps the FE error through the model the study measured (its gap + that model's own
    surrogate error: the mesh's bound), adds this model's surrogate error end to end,
    rewrites report.md and the manifest's sha256 of it, leaves the ONNX graph and the mesh byte for byte,
    and the folder still reads; a JSON of another mesh is refused with one line, exit 2."""
    import shutil

    from contracts.files import sha256

    model = tmp_path / "m"
    shutil.copytree(tiny_model, model)
    before = read_model_folder(model).manifest
    gaps = {"markers": 0.12, "prostate_surface": 0.31, "all_nodes": 0.9}
    run = _cli("restamp", "--model", model, "--fe-error", _model_vs_converged(model, tmp_path, gaps))
    assert run.returncode == 0, run.stderr
    after = read_model_folder(model).manifest
    for name, gap in gaps.items():
        r = after.accuracy.regions[name]
        assert r.surrogate_mm == before.accuracy.regions[name].surrogate_mm
        assert r.fe_discretisation_mm == pytest.approx(gap + MEASURED_SURROGATE[name])
        assert r.end_to_end_mm == pytest.approx(r.surrogate_mm + r.fe_discretisation_mm)
    assert "taylor-hood" in after.accuracy.reference
    # each case names the levels it was judged on (a case the finest level has not solved: the three below)
    assert "levels of 200 / 400 / 800 tets for 10 mm, 0 deg; levels of 100 / 200 / 400 tets for 10 mm, 10 deg" \
        in after.accuracy.reference
    assert f"{after.accuracy.regions['markers'].end_to_end_mm:.3f}" in (model / "report.md").read_text()
    assert f"end to end at the markers {after.accuracy.regions['markers'].end_to_end_mm:.3f}" in run.stdout
    for name in ("model.onnx", "mesh.npz"):
        assert after.files[name] == before.files[name] == sha256(model / name)
    assert after.model_dump(exclude={"accuracy", "files"}) == before.model_dump(exclude={"accuracy", "files"})
    wrong = _cli("restamp", "--model", model, "--fe-error", _model_vs_converged(model, tmp_path, gaps, n_tets=7))
    assert wrong.returncode == 2 and wrong.stderr.startswith("error: --fe-error:") and "Traceback" not in wrong.stderr
    unstated = _cli("restamp", "--model", model, "--fe-error",
                    _model_vs_converged(model, tmp_path, gaps, measured=None))
    assert unstated.returncode == 2 and "model_surrogate_mm" in unstated.stderr
    assert read_model_folder(model).manifest == after
