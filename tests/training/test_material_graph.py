"""The material model's ONNX graph against torch and a float64 numpy reference, its branches, and the first-order
std against finite differences of the graph itself."""

import numpy as np
import pytest
import torch

from contracts.model import onnx_session
from training.export import folded_layers, read_weights
from training.material_graph import build_material_graph, reference_decode_materials
from training.network import train
from training.pca import fit_pca

M = 3  # material inputs


@pytest.fixture(scope="module")
def pieces():
    """u = d f(d, beta) and S_i = d s_i(d, beta) on 400 nodes, one basis for both, (1 + M) x rank network outputs."""
    rng = np.random.default_rng(1)
    n_nodes, rank = 400, 6
    x = np.stack([rng.uniform(0.25, 10, 120), rng.uniform(-10, 10, 120)], axis=1)
    fields = 0.3 * rng.normal(size=(2 + M, 3 * n_nodes))
    f = fields[0] + np.outer(x[:, 1] / 10, fields[1])  # u / d
    s = [0.2 * np.outer(1 + x[:, 0] / 10, fields[2 + i]) for i in range(M)]  # S_i / d
    pca = fit_pca(np.vstack([f, *s]), rank)
    targets = np.hstack([pca.encode(r) for r in (f, *s)])
    net, scaling, _ = train(x, targets, width=20, max_iterations=100)
    return net, scaling, pca


def _torch_decode(net, s, pca, guide, theta, sigma):
    """float32 torch: the network, the (1 + M) fields d (mean + c basis),
    then u0 + S theta and sqrt(sum (S sigma)^2)."""
    with torch.no_grad():
        net32 = net.float()
        coef = net32(torch.from_numpy(((guide - s.input_center) / s.input_scale).astype(np.float32)))
        coef = (coef * torch.from_numpy(s.coef_scale.astype(np.float32))
                + torch.from_numpy(s.coef_mean.astype(np.float32)))
        coef = coef.reshape(len(guide), 1 + M, -1)
        fields = torch.from_numpy(pca.mean.astype(np.float32)) + coef @ torch.from_numpy(pca.basis.astype(np.float32))
        fields = fields * torch.from_numpy(guide[:, :1, None])
        th, sg = torch.from_numpy(theta)[:, :, None], torch.from_numpy(sigma)[:, :, None]
        u = fields[:, 0] + (fields[:, 1:] * th).sum(dim=1)
        std = ((fields[:, 1:] * sg) ** 2).sum(dim=1).sqrt()
        net.double()
    return u.numpy().reshape(len(guide), -1, 3), std.numpy().reshape(len(guide), -1, 3)


def test_onnx_torch_numpy_parity_of_the_material_inputs(pieces):
    """float32 onnxruntime, float32 torch and float64 numpy agree within 1e-4 mm, displacement and std, at the
    envelope's corners and the material ranges' ends (theta +-0.4)."""
    net, s, pca = pieces
    guide = np.array([[0, -10], [10, -10], [0, 10], [10, 10], [5.3, 1.7]], dtype=np.float32)
    theta = np.array([[0.4, -0.4, 0.0], [-0.4, 0.4, 0.4], [0.1, 0.2, -0.3], [0.4, 0.4, 0.4], [0, 0, 0]], np.float32)
    sigma = np.array([[0.2, 0.2, 0.2], [0.1, 0.0, 0.3], [0.2, 0.1, 0.0], [0.05, 0.2, 0.2], [0.2, 0.2, 0.2]], np.float32)
    layers = folded_layers(net, s)
    ref_u, ref_std = reference_decode_materials(layers, pca, M, guide, theta, sigma)
    onnx_u, onnx_std = onnx_session(build_material_graph(layers, pca, M).SerializeToString()).run(
        ["displacement", "displacement_std"], {"guide": guide, "materials": theta, "materials_std": sigma})
    torch_u, torch_std = _torch_decode(net, s, pca, guide, theta, sigma)
    assert np.abs(ref_u).max() > 1 and np.abs(ref_std).max() > 0.1
    for ours in (onnx_u, torch_u):
        np.testing.assert_allclose(ours, ref_u, atol=1e-4)
    for ours in (onnx_std, torch_std):
        np.testing.assert_allclose(ours, ref_std, atol=1e-4)


def test_the_subset_branch_and_the_defaults(pieces):
    """The node subset decodes the same rows as the full mesh; left out, materials are nominal and std zero; the
    guide at rest gives exactly zero displacement and std."""
    net, s, pca = pieces
    sess = onnx_session(build_material_graph(folded_layers(net, s), pca, M).SerializeToString())
    guide = np.array([[4.0, 3.0], [0.0, -5.0]], dtype=np.float32)
    theta, sigma = np.full((2, M), 0.3, np.float32), np.full((2, M), 0.2, np.float32)
    ids = np.array([399, 0, 17])
    full = sess.run(None, {"guide": guide, "materials": theta, "materials_std": sigma})
    part = sess.run(None, {"guide": guide, "materials": theta, "materials_std": sigma, "nodes": ids})
    for a, b in zip(full, part):
        np.testing.assert_allclose(b, a[:, ids], atol=1e-5)
    nominal, std = sess.run(None, {"guide": guide})
    zero = sess.run(None, {"guide": guide, "materials": np.zeros((2, M), np.float32)})[0]
    np.testing.assert_array_equal(nominal, zero)
    assert np.all(std == 0.0) and np.all(full[0][1] == 0.0) and np.all(full[1][1] == 0.0)


def test_the_std_is_the_first_order_propagation_of_the_graphs_own_finite_differences(pieces):
    """std_k = sqrt(sum_i ((u(theta + h e_i) - u(theta - h e_i)) / 2h)^2 sigma_i^2), the graph being linear in theta."""
    net, s, pca = pieces
    sess = onnx_session(build_material_graph(folded_layers(net, s), pca, M).SerializeToString())
    guide, sigma = np.array([[7.0, -4.0]], np.float32), np.array([[0.2, 0.1, 0.3]], np.float32)
    h = 0.25
    unit = np.eye(M, dtype=np.float32)
    slopes = [(sess.run(["displacement"], {"guide": guide, "materials": h * unit[i:i + 1]})[0]
               - sess.run(["displacement"], {"guide": guide, "materials": -h * unit[i:i + 1]})[0])
              / (2 * h) for i in range(M)]
    expected = np.sqrt(sum((d * sg) ** 2 for d, sg in zip(slopes, sigma[0])))
    std = sess.run(["displacement_std"], {"guide": guide, "materials_std": sigma})[0]
    np.testing.assert_allclose(std, expected, atol=2e-5 * np.abs(expected).max())


def test_material_graph_rebuilds_byte_for_byte_from_its_own_weights(pieces):
    """Read back and built again from its weights, the material graph gives the same bytes, float32 and float16
    basis: `python -m training regraph` changes a model folder only where today's builder differs."""
    net, s, pca = pieces
    for dtype in (np.float32, np.float16):
        built = build_material_graph(folded_layers(net, s), pca, M, dtype=dtype).SerializeToString()
        layers, read_pca, read_dtype = read_weights(built)
        assert build_material_graph(layers, read_pca, M, dtype=read_dtype).SerializeToString() == built
