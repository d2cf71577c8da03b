"""Build the ONNX graph: normalise -> MLP -> PCA decoder, decoding all nodes or a chosen subset.

Inputs:  guide float32 [batch, 2] = (displacement_mm, angle_deg)
         nodes int64 [k], optional (default: empty = every node)
Output:  displacement float32 [batch, k or n_nodes, 3] in mm

The model is u(d, beta) = d f(d, beta): the PCA and the network fit f = u / d, and the graph
multiplies by d. So the guide at rest (d = 0) gives exactly zero, by construction. The factor costs
nothing in the decode: u = [d c, d] . [basis; mean], one Gemm with one more column than the rank.

An `If` on `Size(nodes) > 0` picks the branch, and onnxruntime runs only the branch taken: a
full-mesh call is one Gemm over the basis; a subset call gathers the 3k basis rows first and
costs O(k * rank). With 312k nodes, rank 32, one thread: full 3.4 ms, 886 nodes 0.03 ms.
Rejected after measuring: two outputs in one graph (onnxruntime ran the full decode even when
only the subset output was fetched), and a `nodes` input defaulting to every node (copies the
whole basis on each call). A second graph for subsets would store the basis twice.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from .network import Mlp, Scaling
from .pca import Pca

OPSET = 17


def _init(name: str, array: np.ndarray) -> onnx.TensorProto:
    return numpy_helper.from_array(np.ascontiguousarray(array), name)


def folded_layers(net: Mlp, scaling: Scaling) -> list[tuple[np.ndarray, np.ndarray]]:
    """(W (in, out), b (out,)) per linear layer, float64, with both scalings folded in."""
    layers = [(m.weight.detach().double().numpy().T.copy(), m.bias.detach().double().numpy().copy())
              for m in net.linears()]
    w, b = layers[0]
    layers[0] = (w / scaling.input_scale[:, None], b - (scaling.input_center / scaling.input_scale) @ w)
    w, b = layers[-1]
    layers[-1] = (w * scaling.coef_scale, b * scaling.coef_scale + scaling.coef_mean)
    return layers


def reference_decode(layers, pca: Pca, guide: np.ndarray) -> np.ndarray:
    """Float64 numpy forward pass of the exported graph: (batch, 2) -> (batch, n_nodes, 3), u = d f."""
    h = np.asarray(guide, dtype=np.float64)
    d = h[:, :1]
    for w, b in layers[:-1]:
        h = np.tanh(h @ w + b)
    w, b = layers[-1]
    return (d * pca.decode(h @ w + b)).reshape(len(h), -1, 3)


def network_nodes(layers) -> tuple[list, list]:
    """The network's initializers and nodes: d = guide[:, :1] (the factor of u = d f), then a Gemm per layer
    (Tanh between) from `guide` to `coefficients`."""
    inits, nodes, h = [], [helper.make_node("Slice", ["guide", "zero1", "one1", "one1"], ["d"])], "guide"
    for i, (w, b) in enumerate(layers):
        inits += [_init(f"w{i}", w.astype(np.float32)), _init(f"b{i}", b.astype(np.float32))]
        out = "coefficients" if i == len(layers) - 1 else f"z{i}"
        nodes.append(helper.make_node("Gemm", [h, f"w{i}", f"b{i}"], [out]))
        if i < len(layers) - 1:
            nodes.append(helper.make_node("Tanh", [out], [f"h{i}"]))
            h = f"h{i}"
    return inits, nodes


def build_graph(layers, pca: Pca, *, dtype=np.float32) -> onnx.ModelProto:
    """The ONNX model; `dtype` is the basis precision (float16 halves its size, computed in float32)."""
    n_comp = pca.basis.shape[1]
    inits = [
        # node-major (3 n_nodes, rank + 1), the mean as the last column: a subset gathers contiguous
        # rows (10x faster than gathering columns of (rank, 3 n_nodes), measured), and the full Gemm
        # with transB runs as fast
        _init("basis", np.ascontiguousarray(np.vstack([pca.basis, pca.mean]).T).astype(dtype)),
    ]
    net_inits, nodes = network_nodes(layers)
    inits += net_inits
    nodes += [  # [d c, d] (batch, rank + 1), so that u = [d c, d] . [basis; mean]^T
        helper.make_node("Mul", ["coefficients", "d"], ["d_coefficients"]),
        helper.make_node("Concat", ["d_coefficients", "d"], ["weights"], axis=1),
    ]
    basis = "basis"
    if dtype != np.float32:
        nodes.append(helper.make_node("Cast", ["basis"], ["basis32"], to=TensorProto.FLOAT))
        basis = "basis32"
    out_info = [helper.make_tensor_value_info("displacement", TensorProto.FLOAT, ["batch", "k", 3])]
    full = helper.make_graph(
        [
            helper.make_node("Gemm", ["weights", basis], ["flat_full"], transB=1),
            helper.make_node("Reshape", ["flat_full", "shape_out"], ["displacement_full"]),
        ],
        "full_mesh", [], [helper.make_tensor_value_info("displacement_full", TensorProto.FLOAT, ["batch", n_comp // 3, 3])],
    )
    subset = helper.make_graph(
        [  # components 3i, 3i+1, 3i+2 of each requested node i, then the same decode
            helper.make_node("Unsqueeze", ["nodes", "axis1"], ["nodes_col"]),
            helper.make_node("Mul", ["nodes_col", "three"], ["first"]),
            helper.make_node("Add", ["first", "xyz"], ["comp_2d"]),
            helper.make_node("Reshape", ["comp_2d", "flat"], ["comp"]),
            helper.make_node("Gather", [basis, "comp"], ["basis_k"], axis=0),
            helper.make_node("Gemm", ["weights", "basis_k"], ["flat_k"], transB=1),
            helper.make_node("Reshape", ["flat_k", "shape_out"], ["displacement_k"]),
        ],
        "node_subset", [], [helper.make_tensor_value_info("displacement_k", TensorProto.FLOAT, ["batch", "k", 3])],
    )
    nodes += [
        helper.make_node("Size", ["nodes"], ["n_requested"]),
        helper.make_node("Greater", ["n_requested", "zero"], ["is_subset"]),
        helper.make_node("If", ["is_subset"], ["displacement"], then_branch=subset, else_branch=full),
    ]
    inits += [
        _init("zero", np.array(0, dtype=np.int64)),
        _init("zero1", np.array([0], dtype=np.int64)),
        _init("one1", np.array([1], dtype=np.int64)),
        _init("axis1", np.array([1], dtype=np.int64)),
        _init("xyz", np.arange(3, dtype=np.int64)[None, :]),
        _init("three", np.array(3, dtype=np.int64)),
        _init("flat", np.array([-1], dtype=np.int64)),
        _init("shape_out", np.array([0, -1, 3], dtype=np.int64)),
        _init("nodes", np.zeros(0, dtype=np.int64)),  # default of the optional input: every node
    ]
    graph = helper.make_graph(
        nodes,
        "prostate_deformation",
        inputs=[
            helper.make_tensor_value_info("guide", TensorProto.FLOAT, ["batch", 2]),
            helper.make_tensor_value_info("nodes", TensorProto.INT64, ["k"]),
        ],
        outputs=out_info,
        initializer=inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="prostate-deform")
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model
