"""The ONNX graph against torch and a float64 numpy reference, the subset branch, the model folder."""


import numpy as np
from contracts.model import onnx_session
import pytest
import torch

from training.export import OPSET, build_graph, folded_layers, read_weights, reference_decode
from training.network import train
from training.pca import fit_pca


@pytest.fixture(scope="module")
def pieces():
    rng = np.random.default_rng(0)
    n_nodes = 500
    x = np.stack([rng.uniform(0.25, 10, 120), rng.uniform(-10, 10, 120)], axis=1)
    fields = 0.3 * rng.normal(size=(3, 3 * n_nodes))  # peak |u| about 10 mm, like the phantom
    u = (np.outer(x[:, 0], fields[0]) + np.outer(x[:, 0] * x[:, 1] / 10, fields[1])
         + np.outer(x[:, 0] ** 2 / 10, fields[2]))
    f = u / x[:, :1]  # the graph decodes f and multiplies by d
    pca = fit_pca(f, 6)
    net, scaling, _ = train(x, pca.encode(f), width=20, max_iterations=100)
    return net, scaling, pca


def _session(model):
    return onnx_session(model.SerializeToString())


def test_onnx_torch_numpy_parity(pieces):
    """float32 onnxruntime, float32 torch and float64 numpy agree within 1e-4 mm at the envelope's corners."""
    net, s, pca = pieces
    guide = np.array([[0, -10], [10, -10], [0, 10], [10, 10], [5.3, 1.7]], dtype=np.float32)
    layers = folded_layers(net, s)
    reference = reference_decode(layers, pca, guide)
    onnx_out = _session(build_graph(layers, pca)).run(None, {"guide": guide})[0]
    with torch.no_grad():
        net32 = net.float()
        coef = net32(torch.from_numpy(((guide - s.input_center) / s.input_scale).astype(np.float32)))
        coef = (coef * torch.from_numpy(s.coef_scale.astype(np.float32))
                + torch.from_numpy(s.coef_mean.astype(np.float32)))
        torch_out = (torch.from_numpy(pca.mean.astype(np.float32))
                     + coef @ torch.from_numpy(pca.basis.astype(np.float32)))
        torch_out = torch_out * torch.from_numpy(guide[:, :1])  # u = d f
        net.double()
    torch_out = torch_out.numpy().reshape(len(guide), -1, 3)
    scale = np.abs(reference).max()
    assert np.abs(onnx_out - reference).max() < 1e-4 and np.abs(torch_out - reference).max() < 1e-4, scale
    assert np.abs(onnx_out - torch_out).max() < 1e-4


def test_guide_at_rest_gives_exactly_zero_in_both_branches(pieces):
    """u = d f by construction: d = 0 decodes to 0.0 exactly (not merely small) at every angle."""
    net, s, pca = pieces
    sess = _session(build_graph(folded_layers(net, s), pca))
    guide = np.array([[0.0, -10.0], [0.0, 0.0], [0.0, 7.5]], dtype=np.float32)
    assert np.all(sess.run(None, {"guide": guide})[0] == 0.0)
    assert np.all(sess.run(None, {"guide": guide, "nodes": np.array([3, 1, 499])})[0] == 0.0)
    assert np.abs(sess.run(None, {"guide": np.array([[0.01, 0.0]], dtype=np.float32)})[0]).max() > 0


def test_subset_branch_decodes_exactly_the_requested_nodes(pieces):
    net, s, pca = pieces
    layers = folded_layers(net, s)
    sess = _session(build_graph(layers, pca))
    guide = np.array([[7.0, -3.0], [2.0, 4.0]], dtype=np.float32)
    full = sess.run(None, {"guide": guide})[0]
    ids = np.array([499, 0, 17, 17, 250])
    sub = sess.run(None, {"guide": guide, "nodes": ids})[0]
    assert sub.shape == (2, 5, 3)
    np.testing.assert_allclose(sub, full[:, ids], atol=1e-6)


def test_float16_basis_halves_the_basis_and_stays_close(pieces):
    net, s, pca = pieces
    layers = folded_layers(net, s)
    m32, m16 = build_graph(layers, pca), build_graph(layers, pca, dtype=np.float16)
    guide = np.array([[10.0, 10.0]], dtype=np.float32)
    a, b = _session(m32).run(None, {"guide": guide})[0], _session(m16).run(None, {"guide": guide})[0]
    assert m16.ByteSize() < 0.6 * m32.ByteSize()
    assert np.abs(a - b).max() < 2e-3 * np.abs(a).max()


def test_graph_rebuilds_byte_for_byte_from_its_own_weights(pieces):
    """The graph is a function of its weights alone: read back and built again it gives the same bytes, float32 and
    float16 basis (what `python -m training regraph` relies on)."""
    net, s, pca = pieces
    for dtype in (np.float32, np.float16):
        built = build_graph(folded_layers(net, s), pca, dtype=dtype).SerializeToString()
        layers, read_pca, read_dtype = read_weights(built)
        assert read_dtype is dtype
        assert build_graph(layers, read_pca, dtype=read_dtype).SerializeToString() == built


def test_graph_carries_only_what_its_nodes_use_at_the_one_opset(pieces):
    """Every initializer is named by a node (the shared index constants included) and the opset is OPSET."""
    net, s, pca = pieces
    model = build_graph(folded_layers(net, s), pca, dtype=np.float16)
    named, stack = set(), list(model.graph.node)
    while stack:
        node = stack.pop()
        named.update(node.input)
        stack += [n for a in node.attribute if a.HasField("g") for n in a.g.node]
    assert {i.name for i in model.graph.initializer} <= named
    assert [(o.domain, o.version) for o in model.opset_import] == [("", OPSET)]
