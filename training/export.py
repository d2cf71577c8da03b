"""Build the ONNX graph: normalise -> MLP -> PCA decoder, decoding all nodes or a chosen subset.

Inputs:  guide float32 [batch, 2] = (displacement_mm, angle_deg)
         nodes int64 [k], optional (default: empty = every node)
Output:  displacement float32 [batch, k or n_nodes, 3] in mm

The model is u(d, beta) = d f(d, beta): the PCA and the network fit f = u / d, and the graph
multiplies by d. So the guide at rest (d = 0) gives exactly zero, by construction. The factor costs
nothing in the decode: u = [d c, d] . [basis; mean], one Gemm with one more column than the rank.

This module is the one graph builder: the network's nodes, the basis, the decode of every node or of a
node subset, and the checked model at OPSET. material_graph.py builds the material model from the same
pieces, adding its inputs between the network and the decode.

An `If` on `Size(nodes) > 0` picks the branch, and onnxruntime runs only the branch taken: a
full-mesh call is one Gemm over the basis; a subset call gathers the 3k basis rows first and
costs O(k * rank), not O(n_nodes * rank), which is why the service's marker requests are far cheaper
than full-mesh ones (docs/results/bench_service.json). Rejected after measuring: two
outputs in one graph (onnxruntime ran the full decode even when only the subset output was fetched),
and a `nodes` input defaulting to every node (copies the whole basis on each call). A second graph for
subsets would store the basis twice.
"""

from __future__ import annotations

import itertools

import numpy as np
import onnx
from onnx import AttributeProto, TensorProto, helper, numpy_helper

from .network import Mlp, Scaling
from .pca import Pca

OPSET = 17  # of every graph built here; the manifest records it (fit.py)
IR_VERSION = 8
PRODUCER = "prostate-deform"

# The int64 constants the graphs' index arithmetic names; a graph carries those its nodes use (constants()).
INDEX_CONSTANTS = {
    "zero": np.array(0, dtype=np.int64),
    "zero1": np.array([0], dtype=np.int64),
    "one1": np.array([1], dtype=np.int64),
    "axis1": np.array([1], dtype=np.int64),
    "axis2": np.array([2], dtype=np.int64),
    "xyz": np.arange(3, dtype=np.int64)[None, :],
    "three": np.array(3, dtype=np.int64),
    "flat": np.array([-1], dtype=np.int64),
    "shape_out": np.array([0, -1, 3], dtype=np.int64),  # (batch, k, 3)
}


def initializer(name: str, array: np.ndarray) -> onnx.TensorProto:
    """A graph initializer `name` holding `array` (made contiguous)."""
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


def reference_network(layers, guide: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Float64 numpy pass of network_nodes: d = guide[:, :1] (batch, 1) and the coefficients (batch, outputs)."""
    h = np.asarray(guide, dtype=np.float64)
    d = h[:, :1]
    for w, b in layers[:-1]:
        h = np.tanh(h @ w + b)
    w, b = layers[-1]
    return d, h @ w + b


def reference_decode(layers, pca: Pca, guide: np.ndarray) -> np.ndarray:
    """Float64 numpy forward pass of the exported graph: (batch, 2) -> (batch, n_nodes, 3), u = d f."""
    d, coefficients = reference_network(layers, guide)
    return (d * pca.decode(coefficients)).reshape(len(d), -1, 3)


def network_nodes(layers, source: str = "guide") -> tuple[list, list]:
    """The network's initializers and nodes: d = guide[:, :1] (the factor of u = d f), then a Gemm per layer
    (Tanh between) from `source` (the guide, or a design model's guide and materials) to `coefficients`."""
    inits, nodes, h = [], [helper.make_node("Slice", ["guide", "zero1", "one1", "one1"], ["d"])], source
    for i, (w, b) in enumerate(layers):
        inits += [initializer(f"w{i}", w.astype(np.float32)), initializer(f"b{i}", b.astype(np.float32))]
        out = "coefficients" if i == len(layers) - 1 else f"z{i}"
        nodes.append(helper.make_node("Gemm", [h, f"w{i}", f"b{i}"], [out]))
        if i < len(layers) - 1:
            nodes.append(helper.make_node("Tanh", [out], [f"h{i}"]))
            h = f"h{i}"
    return inits, nodes


def basis_nodes(pca: Pca, dtype) -> tuple[onnx.TensorProto, list, str]:
    """(the `basis` initializer in `dtype`, the nodes casting it to float32 if it is not, the float32 basis's name).

    Node-major (3 n_nodes, rank + 1), the mean as the last column: a subset gathers contiguous rows, much
    faster than gathering columns of (rank, 3 n_nodes) (CHANGELOG, issue 50), and the full Gemm with transB
    runs as fast."""
    basis = initializer("basis", np.ascontiguousarray(np.vstack([pca.basis, pca.mean]).T).astype(dtype))
    if dtype != np.float32:
        return basis, [helper.make_node("Cast", ["basis"], ["basis32"], to=TensorProto.FLOAT)], "basis32"
    return basis, [], "basis"


def decode_nodes(weights: str, basis: str, output: str, *, full_shape: list, subset_shape: list,
                 reshape: str | None = None) -> list:
    """Nodes computing `output` = weights . basis^T over every node when the `nodes` input is empty, else over
    the 3k basis rows of the requested nodes only: an If on Size(nodes) > 0, so onnxruntime runs only the branch
    taken. `reshape` (an initializer's name) reshapes each branch's flat rows; `full_shape` and `subset_shape`
    are the shapes of the two branches' outputs."""
    gather = [  # components 3i, 3i+1, 3i+2 of each requested node i
        helper.make_node("Unsqueeze", ["nodes", "axis1"], ["nodes_col"]),
        helper.make_node("Mul", ["nodes_col", "three"], ["first"]),
        helper.make_node("Add", ["first", "xyz"], ["comp_2d"]),
        helper.make_node("Reshape", ["comp_2d", "flat"], ["comp"]),
        helper.make_node("Gather", [basis, "comp"], ["basis_k"], axis=0),
    ]

    def branch(name: str, rows: str, first: list, suffix: str, shape: list) -> onnx.GraphProto:
        nodes, out = [*first, helper.make_node("Gemm", [weights, rows], [f"flat_{suffix}"], transB=1)], f"flat_{suffix}"
        if reshape is not None:
            nodes.append(helper.make_node("Reshape", [out, reshape], [f"{output}_{suffix}"]))
            out = f"{output}_{suffix}"
        return helper.make_graph(nodes, name, [], [helper.make_tensor_value_info(out, TensorProto.FLOAT, shape)])

    return [
        helper.make_node("Size", ["nodes"], ["n_requested"]),
        helper.make_node("Greater", ["n_requested", "zero"], ["is_subset"]),
        helper.make_node("If", ["is_subset"], [output],
                         then_branch=branch("node_subset", "basis_k", gather, "k", subset_shape),
                         else_branch=branch("full_mesh", basis, [], "full", full_shape)),
    ]


def constants(nodes: list) -> list[onnx.TensorProto]:
    """The INDEX_CONSTANTS that `nodes` and the branches of their Ifs name, in the table's order."""
    used, stack = set(), list(nodes)
    while stack:
        node = stack.pop()
        used.update(node.input)
        stack += [n for a in node.attribute if a.type == AttributeProto.GRAPH for n in a.g.node]
    return [initializer(name, value) for name, value in INDEX_CONSTANTS.items() if name in used]


def every_node() -> onnx.TensorProto:
    """The default of the optional `nodes` input: empty, which decodes every node."""
    return initializer("nodes", np.zeros(0, dtype=np.int64))


def checked_model(name: str, nodes: list, initializers: list, *, inputs: list, outputs: list) -> onnx.ModelProto:
    """The model of one graph at OPSET, checked by onnx.checker."""
    graph = helper.make_graph(nodes, name, inputs=inputs, outputs=outputs, initializer=initializers)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name=PRODUCER)
    model.ir_version = IR_VERSION
    onnx.checker.check_model(model)
    return model


def read_weights(model_bytes: bytes) -> tuple[list[tuple[np.ndarray, np.ndarray]], Pca, type]:
    """(float64 network layers, the basis and mean as a Pca without singular values, the basis dtype) of a graph
    built here: what network_nodes and basis_nodes wrote, read back."""
    weights = {i.name: numpy_helper.to_array(i) for i in onnx.load_from_string(model_bytes).graph.initializer}
    layers = [(weights[f"w{i}"].astype(np.float64), weights[f"b{i}"].astype(np.float64))
              for i in itertools.takewhile(lambda i: f"w{i}" in weights, itertools.count())]
    stacked = weights["basis"].T.astype(np.float64)  # (rank + 1, 3 n_nodes): the basis rows, then the mean
    return layers, Pca(mean=stacked[-1], basis=stacked[:-1], singular_values=np.ones(1)), weights["basis"].dtype.type


def build_graph(layers, pca: Pca, *, dtype=np.float32) -> onnx.ModelProto:
    """The ONNX model; `dtype` is the basis precision (float16 halves its size, computed in float32)."""
    n_comp = pca.basis.shape[1]
    basis_init, cast, basis = basis_nodes(pca, dtype)
    net_inits, nodes = network_nodes(layers)
    nodes += [  # [d c, d] (batch, rank + 1), so that u = [d c, d] . [basis; mean]^T
        helper.make_node("Mul", ["coefficients", "d"], ["d_coefficients"]),
        helper.make_node("Concat", ["d_coefficients", "d"], ["weights"], axis=1),
        *cast,
        *decode_nodes("weights", basis, "displacement", reshape="shape_out",
                      full_shape=["batch", n_comp // 3, 3], subset_shape=["batch", "k", 3]),
    ]
    return checked_model(
        "prostate_deformation", nodes, [basis_init, *net_inits, *constants(nodes), every_node()],
        inputs=[helper.make_tensor_value_info("guide", TensorProto.FLOAT, ["batch", 2]),
                helper.make_tensor_value_info("nodes", TensorProto.INT64, ["k"])],
        outputs=[helper.make_tensor_value_info("displacement", TensorProto.FLOAT, ["batch", "k", 3])],
    )
