"""The ONNX graph of a material model: u0 and the m sensitivities decoded by one basis, combined to first order.

Inputs:  guide float32 [batch, 2] = (displacement_mm, angle_deg)
         materials float32 [batch, m], optional (default 0): theta_i = ln(E_i / E_i,nominal), manifest order
         materials_std float32 [batch, m], optional (default 0): sigma_i, the std of ln E_i
         nodes int64 [k], optional (default: empty = every node)
Outputs: displacement float32 [batch, k, 3] mm      u0 + sum_i theta_i S_i
         displacement_std float32 [batch, k, 3] mm  sqrt(sum_i (sigma_i S_i)^2), per component

The network gives (1 + m) x rank coefficients per case: c_0 for f0 = u0 / d and c_i for S_i / d, all decoded by
the same PCA basis (fitted on the u and the S rows together) as d (mean + c basis), as export.py decodes u.
Both outputs are linear in the fields before the square root, so the weights are combined before the decode: u's row
is [1, theta] . w (one row) and the std's rows are sigma_i w_i; the 1 + m rows are one Gemm of (batch (1 + m),
rank + 1) weights with the basis, in either branch of the `If` on the node subset, so a subset call still gathers
only its 3k basis rows. The variance sum_i (sigma_i S_i)^2 is a MatMul with ones over the m rows, not
onnxruntime's Mul + ReduceSum over that axis (the graph's first form), which cost half as much as the Gemm itself
(CHANGELOG: the entry where `training regraph` rebuilt models/default with it).

The graph is export.py's, extended: the same network nodes, basis and node-subset decode, with the material
inputs combined into the decode's weights before it and the std taken after it.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper

from .export import (basis_nodes, checked_model, constants, decode_nodes, every_node, initializer, network_nodes,
                     reference_network)
from .pca import Pca


def reference_decode_materials(layers, pca: Pca, n_materials: int, guide: np.ndarray, theta: np.ndarray | None = None,
                               sigma: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Float64 numpy forward pass: (displacement, displacement_std), each (batch, n_nodes, 3)."""
    d, coefficients = reference_network(layers, guide)
    coef = coefficients.reshape(len(d), 1 + n_materials, -1)  # (batch, 1 + m, rank)
    fields = d[:, :, None] * pca.decode(coef)  # (batch, 1 + m, 3 n_nodes)
    theta = np.zeros((len(d), n_materials)) if theta is None else np.asarray(theta, dtype=np.float64)
    sigma = np.zeros((len(d), n_materials)) if sigma is None else np.asarray(sigma, dtype=np.float64)
    u = fields[:, 0] + np.einsum("bm,bmn->bn", theta, fields[:, 1:])
    std = np.sqrt(np.einsum("bm,bmn->bn", sigma**2, fields[:, 1:] ** 2))
    return u.reshape(len(d), -1, 3), std.reshape(len(d), -1, 3)


def reference_decode_design(layers, pca: Pca, n_materials: int, guide: np.ndarray, theta: np.ndarray | None = None,
                            sigma: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Float64 numpy forward pass of a design model's graph (jacobian=True): u = d (mean + c(d, beta, theta) basis),
    S_i = d (dc / dtheta_i) basis; (displacement, displacement_std), each (batch, n_nodes, 3)."""
    from .sobolev import jacobian

    guide = np.asarray(guide, dtype=np.float64)
    theta = np.zeros((len(guide), n_materials)) if theta is None else np.asarray(theta, dtype=np.float64)
    sigma = np.zeros((len(guide), n_materials)) if sigma is None else np.asarray(sigma, dtype=np.float64)
    c, dc = jacobian(layers, np.hstack([guide, theta]), list(range(2, 2 + n_materials)))
    d = guide[:, :1]
    u = d * pca.decode(c)
    sens = d[:, :, None] * (dc @ pca.basis)  # (batch, m, 3 n_nodes)
    std = np.sqrt(np.einsum("bm,bmn->bn", sigma**2, sens**2))
    return u.reshape(len(d), -1, 3), std.reshape(len(d), -1, 3)


def _jacobian_nodes(layers, m: int) -> tuple[list, list]:
    """A design model's network (module docstring of training/sobolev.py) from Concat(guide, materials), and its
    own Jacobian in theta, appended to c as `coefficients_all` (batch, (1 + m) rank): dc / dtheta_i =
    ((1 - h^2) * W1[2 + i]) W2, the S_i / d coefficients, with no mean."""
    (w1, _), _ = layers
    inits, nodes = network_nodes(layers, source="net_in")
    nodes = [helper.make_node("Shape", ["guide"], ["jac_guide_shape"]),  # materials' default is one row: broadcast it
             helper.make_node("Slice", ["jac_guide_shape", "zero1", "one1"], ["jac_batch"]),
             helper.make_node("Concat", ["jac_batch", "jac_m"], ["jac_materials_shape"], axis=0),
             helper.make_node("Expand", ["materials", "jac_materials_shape"], ["jac_materials"]),
             helper.make_node("Concat", ["guide", "jac_materials"], ["net_in"], axis=1), *nodes,
             helper.make_node("Mul", ["h0", "h0"], ["jac_h2"]),
             helper.make_node("Sub", ["jac_one", "jac_h2"], ["jac_slope"]),
             helper.make_node("Unsqueeze", ["jac_slope", "one1"], ["jac_slope3"]),  # (batch, 1, width)
             helper.make_node("Mul", ["jac_slope3", "jac_w_theta"], ["jac_hidden"]),  # (batch, m, width)
             helper.make_node("MatMul", ["jac_hidden", "w1"], ["jac_c"]),  # (batch, m, rank)
             helper.make_node("Reshape", ["jac_c", "jac_flat"], ["jac_c_flat"]),
             helper.make_node("Concat", ["coefficients", "jac_c_flat"], ["coefficients_all"], axis=1)]
    inits += [initializer("jac_one", np.ones(1, dtype=np.float32)),
              initializer("jac_w_theta", w1[2:2 + m].astype(np.float32)),
              initializer("jac_flat", np.array([0, -1], dtype=np.int64)),
              initializer("jac_m", np.array([m], dtype=np.int64))]
    return inits, nodes


def build_material_graph(layers, pca: Pca, n_materials: int, *, dtype=np.float32,
                         jacobian: bool = False) -> onnx.ModelProto:
    """The material model's ONNX graph (module docstring); `dtype` is the basis precision. With `jacobian`, a design
    model's: the network takes theta, u is its decode at theta, and the S_i are its Jacobian's (no first order)."""
    if jacobian and len(layers) != 2:
        raise ValueError("--depth: a design model's graph computes the Jacobian of one hidden layer, got "
                         f"{len(layers) - 1}")
    m, n_comp, rank = n_materials, pca.basis.shape[1], pca.basis.shape[0]
    basis_init, cast, basis = basis_nodes(pca, dtype)
    net_inits, nodes = _jacobian_nodes(layers, m) if jacobian else network_nodes(layers)
    if jacobian:  # u's row is c alone; the S_i rows carry no mean (they are derivatives)
        shift = [helper.make_node("Identity", ["w_0"], ["w_u"])]
        ones_fields = np.zeros((1, 1 + m, 1), dtype=np.float32)
        ones_fields[0, 0] = 1.0
    else:
        shift = [helper.make_node("Unsqueeze", ["materials", "one1"], ["theta3"]),
                 helper.make_node("MatMul", ["theta3", "w_s"], ["w_shift"]),
                 helper.make_node("Add", ["w_0", "w_shift"], ["w_u"])]
        ones_fields = np.ones((1, 1 + m, 1), dtype=np.float32)
    nodes += [
        *cast,
        # weights [d c_j, d] per field j (batch, 1 + m, rank + 1), as rows (batch (1 + m), rank + 1)
        helper.make_node("Reshape", ["coefficients_all" if jacobian else "coefficients", "coef_shape"], ["coef3"]),
        helper.make_node("Unsqueeze", ["d", "axis2"], ["d3"]),
        helper.make_node("Mul", ["coef3", "d3"], ["d_coef3"]),
        helper.make_node("Mul", ["ones_fields", "d3"], ["d_col"]),
        helper.make_node("Concat", ["d_coef3", "d_col"], ["w3"], axis=2),
        # u's weights [1, theta] . w3 (u is linear in the fields), then the std rows sigma_i w3_i
        helper.make_node("Slice", ["w3", "zero1", "one1", "one1"], ["w_0"]),
        helper.make_node("Slice", ["w3", "one1", "m_end", "one1"], ["w_s"]),
        *shift,
        helper.make_node("Unsqueeze", ["materials_std", "axis2"], ["sigma3"]),
        helper.make_node("Mul", ["w_s", "sigma3"], ["w_sigma"]),
        helper.make_node("Concat", ["w_u", "w_sigma"], ["w_rows"], axis=1),
        helper.make_node("Reshape", ["w_rows", "w_shape"], ["w2"]),
        # the flat fields (batch (1 + m), 3k) of every node or of the requested ones
        *decode_nodes("w2", basis, "flat_fields", full_shape=["rows", n_comp], subset_shape=["rows", "k3"]),
        # rows (batch, 1 + m, k, 3): u, then sigma_i S_i
        helper.make_node("Shape", ["guide"], ["guide_shape"]),
        helper.make_node("Slice", ["guide_shape", "zero1", "one1"], ["batch"]),
        helper.make_node("Concat", ["batch", "fields_tail"], ["fields_shape"], axis=0),
        helper.make_node("Reshape", ["flat_fields", "fields_shape"], ["fields"]),
        helper.make_node("Slice", ["fields", "zero1", "one1", "one1"], ["u_4"]),
        helper.make_node("Squeeze", ["u_4", "one1"], ["displacement"]),
        helper.make_node("Slice", ["fields", "one1", "m_end", "one1"], ["sens_sigma"]),
        helper.make_node("Mul", ["sens_sigma", "sens_sigma"], ["variance_terms"]),
        helper.make_node("Concat", ["batch", "terms_tail"], ["terms_shape"], axis=0),
        helper.make_node("Reshape", ["variance_terms", "terms_shape"], ["terms3"]),  # (batch, m, 3k)
        helper.make_node("MatMul", ["ones_m", "terms3"], ["variance3"]),  # (batch, 1, 3k)
        helper.make_node("Concat", ["batch", "xyz_tail"], ["out_shape"], axis=0),
        helper.make_node("Reshape", ["variance3", "out_shape"], ["variance"]),
        helper.make_node("Sqrt", ["variance"], ["displacement_std"]),
    ]
    shapes = [  # the constants that depend on m and the rank
        initializer("coef_shape", np.array([0, 1 + m, rank], dtype=np.int64)),
        initializer("w_shape", np.array([-1, rank + 1], dtype=np.int64)),
        initializer("ones_fields", ones_fields),
        initializer("fields_tail", np.array([1 + m, -1, 3], dtype=np.int64)),
        initializer("m_end", np.array([1 + m], dtype=np.int64)),
        initializer("ones_m", np.ones((1, m), dtype=np.float32)),
        initializer("terms_tail", np.array([m, -1], dtype=np.int64)),
        initializer("xyz_tail", np.array([-1, 3], dtype=np.int64)),
    ]
    defaults = [  # of the optional inputs: every node, nominal materials, no std
        every_node(),
        initializer("materials", np.zeros((1, m), dtype=np.float32)),
        initializer("materials_std", np.zeros((1, m), dtype=np.float32)),
    ]
    return checked_model(
        "prostate_deformation_materials", nodes, [basis_init, *net_inits, *constants(nodes), *shapes, *defaults],
        inputs=[helper.make_tensor_value_info("guide", TensorProto.FLOAT, ["batch", 2]),
                helper.make_tensor_value_info("materials", TensorProto.FLOAT, ["batch", m]),
                helper.make_tensor_value_info("materials_std", TensorProto.FLOAT, ["batch", m]),
                helper.make_tensor_value_info("nodes", TensorProto.INT64, ["k"])],
        outputs=[helper.make_tensor_value_info("displacement", TensorProto.FLOAT, ["batch", "k", 3]),
                 helper.make_tensor_value_info("displacement_std", TensorProto.FLOAT, ["batch", "k", 3])],
    )
