"""Design models (training/design_fit.py, sobolev.py, material_graph jacobian=True): the graph against its float64
reference, its std against finite differences of its own u, the Sobolev fit's use of derivatives, and on a tiny linear
design over the patient box: held-out accuracy that first order cannot reach, and the service serving it by ratios."""

import numpy as np
import pytest

from contracts.model import onnx_session
from training.material_graph import build_material_graph, reference_decode_design
from training.pca import Pca

from tests.conftest import tiny_box_scene

M = 4


def _random_model(rng, *, n_nodes=30, rank=5, width=7):
    layers = [(rng.normal(size=(2 + M, width)) * 0.5, rng.normal(size=width) * 0.1),
              (rng.normal(size=(width, rank)), rng.normal(size=rank))]
    q, _ = np.linalg.qr(rng.normal(size=(3 * n_nodes, rank)))
    return layers, Pca(mean=rng.normal(size=3 * n_nodes), basis=q.T, singular_values=np.ones(rank))


def test_the_design_graph_computes_its_float64_reference():
    rng = np.random.default_rng(0)
    layers, pca = _random_model(rng)
    session = onnx_session(build_material_graph(layers, pca, M, jacobian=True).SerializeToString())
    guide = np.array([[3.0, -4.0], [7.5, 9.0], [0.5, 0.0]])
    theta, sigma = rng.normal(size=(3, M)) * 0.5, np.abs(rng.normal(size=(3, M))) * 0.2
    u, std = session.run(None, {"guide": guide.astype(np.float32), "materials": theta.astype(np.float32),
                                "materials_std": sigma.astype(np.float32)})
    ref_u, ref_std = reference_decode_design(layers, pca, M, guide, theta, sigma)
    np.testing.assert_allclose(u, ref_u, atol=2e-5 * np.abs(ref_u).max())
    np.testing.assert_allclose(std, ref_std, atol=2e-5 * np.abs(ref_std).max())
    # the materials input left out is the nominal, for every row of a batch
    (u0,) = session.run(["displacement"], {"guide": guide.astype(np.float32)})
    np.testing.assert_allclose(u0, reference_decode_design(layers, pca, M, guide)[0], atol=2e-5 * np.abs(ref_u).max())


def test_the_design_graphs_std_is_the_derivative_of_its_own_displacement():
    """sigma_i |du / dtheta_i| per component from the graph's std with one sigma_i set, against central differences
    of the float64 u: the sensitivities are the model's own Jacobian, so they describe the answer it gives."""
    rng = np.random.default_rng(1)
    layers, pca = _random_model(rng)
    guide, theta, h = np.array([[6.0, 3.0]]), rng.normal(size=(1, M)) * 0.4, 1e-5
    for i in range(M):
        e = np.zeros((1, M))
        e[0, i] = h
        fd = (reference_decode_design(layers, pca, M, guide, theta + e)[0]
              - reference_decode_design(layers, pca, M, guide, theta - e)[0]) / (2 * h)
        sigma = np.zeros((1, M))
        sigma[0, i] = 0.3
        _, std = reference_decode_design(layers, pca, M, guide, theta, sigma)
        np.testing.assert_allclose(std, 0.3 * np.abs(fd), rtol=1e-6, atol=1e-9)


def test_derivative_rows_make_the_fit_right_between_few_points():
    """A smooth function of 3 inputs from 12 points: fitted to values and derivatives, the network is closer to it
    at 400 fresh points than fitted to the values alone, in the values and in the derivatives."""
    from training.sobolev import jacobian, train_sobolev
    from training.export import folded_layers

    rng = np.random.default_rng(2)

    def f(x):
        return np.column_stack([np.sin(x[:, 0] + x[:, 2]), x[:, 1] * np.cos(x[:, 2]), np.exp(0.5 * x[:, 2]) * x[:, 0]])

    def df(x):  # d f / d x_2, (n, 3)
        return np.column_stack([np.cos(x[:, 0] + x[:, 2]), -x[:, 1] * np.sin(x[:, 2]),
                                0.5 * np.exp(0.5 * x[:, 2]) * x[:, 0]])

    x, test = rng.uniform(-1, 1, size=(12, 3)), rng.uniform(-1, 1, size=(400, 3))
    errors = {}
    for grads in (False, True):
        net, scaling, _ = train_sobolev(x, f(x), grad_rows=np.full(len(x), grads), grad_columns=[2],
                                        grad_targets=[df(x)], grad_weights=np.ones(1), width=12, max_iterations=400)
        c, dc = jacobian(folded_layers(net, scaling), test, [2])
        errors[grads] = (np.abs(c - f(test)).max(), np.abs(dc[:, 0] - df(test)).max())
    assert errors[True][0] < 0.5 * errors[False][0] and errors[True][1] < 0.5 * errors[False][1], errors


def test_a_design_model_is_right_at_the_box_corners_where_first_order_is_not(tiny_design, design_model):
    """At the 16 corners of the patient box, fresh FE that no training path used: the design model (16 points) is
    within 0.05 mm everywhere, and five times closer at the markers than first order from the nominal (u0 +
    sum_i S_i theta_i with the FE's own u0 and S_i at the same push and angle, no fit): the box is too wide for it."""
    from contracts.design import read_design
    from contracts.model import read_model_folder
    from contracts.sweep import read_sweep
    from fem_offline.sweep import run_sweep

    acc = read_model_folder(design_model).manifest.accuracy.regions
    assert acc["all_nodes"].surrogate_mm < 0.05
    run_sweep(tiny_box_scene(), tiny_design / "nominal")  # superposed: u0 and S_i on the (d, beta) grid
    nominal, held = read_sweep(tiny_design / "nominal"), read_design(tiny_design / "held")
    markers = held.mesh.node_sets["markers"]
    worst = 0.0
    for x, u in zip(held.inputs, held.displacement):
        (at,) = np.flatnonzero(np.all(np.isclose(nominal.inputs, x[:2]), axis=1))
        first = nominal.displacement[at] + sum(t * nominal.sensitivity[name][at]
                                               for t, name in zip(x[2:], held.design.tissues))
        worst = max(worst, float(np.linalg.norm(first - u, axis=1)[markers].max()))
    assert acc["markers"].surrogate_mm * 5 < worst, (acc["markers"].surrogate_mm, worst)


def test_a_served_design_model_answers_by_ratios(design_model):
    """Every E x k gives the answer of the E it was scaled from; a ratio beyond the box is a 422 naming both tissues."""
    from tests.service.helpers import predict_json, served

    nominal = {"prostate": 50.0, "rectal_wall": 60.0, "adipose": 20.0, "bladder": 150.0}
    with served(design_model) as client:
        one = predict_json(client, displacement_mm=3.0, angle_deg=5.0, region="markers",
                           materials={t: {"youngs_kpa": e} for t, e in nominal.items()})
        scaled = predict_json(client, displacement_mm=3.0, angle_deg=5.0, region="markers",
                              materials={t: {"youngs_kpa": 2.5 * e} for t, e in nominal.items()})
        np.testing.assert_allclose(scaled["positions"], one["positions"], atol=1e-5)
        bad = client.post("/predict", json={"displacement_mm": 3.0, "angle_deg": 5.0, "region": "markers",
                                            "materials": {"rectal_wall": {"youngs_kpa": 1.0},
                                                          "prostate": {"youngs_kpa": 500.0}}})
        assert bad.status_code == 422 and "prostate" in bad.text and "rectal_wall" in bad.text, bad.text


def test_the_design_points_study_gains_accuracy_with_points_and_states_their_cost(tiny_design, tmp_path):
    """`studies design-points` on the tiny design: fitted on its first 16 points the model is closer to the held-out
    corners than on its first 4, and the FE cost is N x the point's snapshots x the measured cost per snapshot."""
    from contracts.model import FitOptions
    from studies.design_points import report, run

    options = FitOptions(rank=10, sensitivity_rank=10, max_iterations=300, test_cases=())
    data = run(tiny_design / "train", tiny_design / "held", [4, 16, 99], options, workers=1, idle_gap_s=300,
               out=tmp_path)
    few, many = data["rows"]
    assert (few["points"], many["points"], data["skipped_points"]) == (4, 16, [99])
    for region in ("markers", "prostate_surface", "all_nodes"):
        assert many["regions"][region]["largest_push_mm"] < 0.5 * few["regions"][region]["largest_push_mm"]
    per = data["cost"]["core_s_per_snapshot"] * data["solved_snapshots_per_point"] / 3600
    assert per > 0 and many["fe_core_hours"] == pytest.approx(16 * per)
    assert few["fe_core_hours"] == pytest.approx(4 * per)
    assert "| 16 |" in report(data) and (tmp_path / "n16" / "model.onnx").is_file()
