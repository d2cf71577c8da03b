"""A material model end to end on the tiny mesh: the manifest's inputs, the graph's inputs and outputs, and the
first-order material model checked against fresh FE solves at the ends of the ranges (training material-check)."""

import json

import numpy as np
import pytest

from contracts.model import onnx_session, read_model_folder
from tests.conftest import TINY_MATERIALS, tiny_material_scene
from training.__main__ import main


def test_a_material_model_lists_its_inputs_in_the_graphs_order(tiny_material_model):
    manifest = read_model_folder(tiny_material_model).manifest
    info = manifest.materials
    assert info.parameter == "ln(E/E_nominal)" and info.tissues == list(TINY_MATERIALS)
    for m in info.inputs:
        assert m.youngs_kpa_range == tuple(TINY_MATERIALS[m.tissue]["youngs_kpa_range"])
        assert m.youngs_kpa_range[0] < m.nominal_youngs_kpa < m.youngs_kpa_range[1] and m.std_percent == 20.0
        assert m.poisson == 0.495 and m.density_kg_m3 == 1008.0
    assert set(manifest.onnx.inputs) == {"guide", "nodes", "materials", "materials_std"}
    assert set(manifest.onnx.outputs) == {"displacement", "displacement_std"}
    assert info.accuracy is None  # until material-check


def test_the_model_reproduces_the_sweeps_sensitivities_at_a_held_out_case(tiny_material_model, tiny_material_sweep):
    """S_i from the graph (theta = e_i minus nominal, exact: linear in theta) against the snapshot's stored S_i at the
    held-out case 5 mm / -2 deg: the surrogate's error on S, small against S itself."""
    from contracts.materials import sensitivity_key

    sess = onnx_session(tiny_material_model / "model.onnx")
    guide = np.array([[5.0, -2.0]], np.float32)
    nominal = sess.run(["displacement"], {"guide": guide})[0][0]
    manifest = json.loads((tiny_material_sweep / "manifest.json").read_text())
    row = next(r for r in manifest["snapshots"] if r["displacement_mm"] == 5.0 and r["angle_deg"] == -2.0)
    with np.load(tiny_material_sweep / row["file"]) as z:
        for i, name in enumerate(TINY_MATERIALS):
            stored = z[sensitivity_key(name)]
            theta = np.eye(len(TINY_MATERIALS), dtype=np.float32)[i:i + 1]
            ours = sess.run(["displacement"], {"guide": guide, "materials": theta})[0][0] - nominal
            assert np.abs(ours - stored).max() < 1e-3 * np.abs(stored).max() + 1e-5, name


@pytest.fixture(scope="module")
def material_cases(tiny_material_sweep, tmp_path_factory):
    """Fresh FE at the ends of two tissues' ranges (and the two alternating corners),
    at 5 mm / 0 deg on the sweep's mesh."""
    from contracts.mesh import read_mesh
    from fem_offline.material_cases import solve_material_cases

    scene = tiny_material_scene(prostate=TINY_MATERIALS["prostate"], adipose=TINY_MATERIALS["adipose"])
    out = tmp_path_factory.mktemp("material_cases")
    solve_material_cases(scene, read_mesh(tiny_material_sweep / "mesh.npz"), out, [(5.0, 0.0)], workers=1)
    return out


def test_material_check_stamps_the_first_order_error_against_fresh_fe(tiny_material_model, material_cases, tmp_path,
                                                                      capsys):
    """u0 + sum S_i theta_i is off the fresh solves by a second-order amount: above zero, and at these |theta| <= 0.28
    (each tissue's range, and both off at once) below a quarter of the first-order change itself (measured: 0.10);
    the ONNX model adds its surrogate error (linear sweep: tiny) to it."""
    import shutil

    model = tmp_path / "model"
    shutil.copytree(tiny_material_model, model)
    assert main(["material-check", "--model", str(model), "--cases", str(material_cases)]) == 0
    acc = read_model_folder(model).manifest.materials.accuracy  # also re-checks every file's sha256
    assert acc.n_points == 6 and "fresh FE" in acc.reference
    with np.load(material_cases / "material_000.npz") as z:
        change = max(np.abs(np.einsum("m,mnk->nk", t, np.stack([z["sensitivity_prostate"], z["sensitivity_adipose"]])))
                     .max() for t in z["theta"])
    for name, r in acc.regions.items():
        assert 0 < r.first_order_mm < 0.25 * change, name
        assert abs(r.model_mm - r.first_order_mm) < 1e-3, name
    assert "first order vs fresh FE" in capsys.readouterr().out


def test_material_check_refuses_a_model_without_material_inputs(tiny_model, material_cases, capsys):
    assert main(["material-check", "--model", str(tiny_model), "--cases", str(material_cases)]) == 2
    assert "takes no material inputs" in capsys.readouterr().err


def test_a_material_point_without_equilibrium_is_kept_counted_and_named(tiny_material_model, tiny_material_sweep,
                                                                       tmp_path, monkeypatch, capsys):
    """A point where the FE finds no equilibrium does not stop the others: its file keeps it (NaN, the message),
    and material-check compares the rest, counts them and names the one it could not compare."""
    import shutil

    from contracts.mesh import read_mesh
    from fem_offline import material_cases as mc
    from fem_offline.fe.newton import ConvergenceError

    solve = mc._fresh

    def corner_fails(scene, mesh, tissues, theta, *rest):
        if np.count_nonzero(theta) > 1:
            raise ConvergenceError("line search found no step")
        return solve(scene, mesh, tissues, theta, *rest)

    monkeypatch.setattr(mc, "_fresh", corner_fails)
    scene = tiny_material_scene(prostate=TINY_MATERIALS["prostate"], adipose=TINY_MATERIALS["adipose"])
    (tmp_path / "cases").mkdir()
    case = mc.solve_material_case(scene, read_mesh(tiny_material_sweep / "mesh.npz"), 5.0, 0.0,
                                  tmp_path / "cases" / "material_000.npz")  # in this process, where the patch is
    with np.load(case) as z:
        assert [bool(f) for f in z["failures"]] == [False] * 4 + [True] * 2
        assert np.isnan(z["fresh"][4:]).all() and np.isfinite(z["fresh"][:4]).all()
    model = tmp_path / "model"
    shutil.copytree(tiny_material_model, model)
    assert main(["material-check", "--model", str(model), "--cases", str(tmp_path / "cases")]) == 0
    acc = read_model_folder(model).manifest.materials.accuracy
    assert acc.n_points == 4 and len(acc.unsolved) == 2 and "line search" in acc.unsolved[0]
    assert all(np.isfinite(r.first_order_mm) and np.isfinite(r.model_mm) for r in acc.regions.values())
    assert capsys.readouterr().out.count("found no equilibrium") == 2


def test_regraph_rebuilds_a_material_graph_from_its_own_weights(tiny_material_model, tmp_path, capsys):
    """The graph rebuilt from the folder's own network, basis and mean answers as the old one (to float32
    round-off, over the guide grid and the range corners), and the folder still reads with every sha256 checked."""
    import shutil

    model = tmp_path / "model"
    shutil.copytree(tiny_material_model, model)
    before = read_model_folder(model).manifest
    assert main(["regraph", "--model", str(model)]) == 0
    assert "model.onnx rebuilt" in capsys.readouterr().out
    after = read_model_folder(model).manifest
    assert after.model_copy(update={"files": before.files}) == before
    m = len(after.materials.inputs)
    g = {"guide": np.array([[4.0, 3.0]], np.float32), "materials": np.linspace(-0.2, 0.1, m, dtype=np.float32)[None],
         "materials_std": np.linspace(0.1, 0.2, m, dtype=np.float32)[None]}
    old = onnx_session(tiny_material_model / "model.onnx").run(None, g)
    new = onnx_session(model / "model.onnx").run(None, g)
    for a, b in zip(old, new):
        np.testing.assert_allclose(b, a, atol=1e-5)


def test_regraph_refuses_a_graph_that_answers_differently_and_writes_nothing(tiny_material_model, tmp_path,
                                                                              monkeypatch, capsys):
    import shutil

    from contracts.files import sha256
    from training import material_graph

    build = material_graph.build_material_graph

    def off_by_a_bit(layers, pca, m, **kw):  # the mean shifted by 1 um: a builder that changed the answer
        return build(layers, type(pca)(mean=pca.mean + 1e-3, basis=pca.basis, singular_values=pca.singular_values), m,
                     **kw)

    monkeypatch.setattr(material_graph, "build_material_graph", off_by_a_bit)
    model = tmp_path / "model"
    shutil.copytree(tiny_material_model, model)
    digests = {f.name: sha256(f) for f in model.iterdir()}
    assert main(["regraph", "--model", str(model)]) == 2
    assert "not written" in capsys.readouterr().err
    assert {f.name: sha256(f) for f in model.iterdir()} == digests


def test_regraph_refuses_a_model_without_material_inputs(tiny_model, capsys):
    assert main(["regraph", "--model", str(tiny_model)]) == 2
    assert "takes no material inputs" in capsys.readouterr().err
