"""A network fitted to values and to derivatives at once (gradient-enhanced, Sobolev): (d, beta, theta) -> c.

A design model (fem_offline.design) answers u(d, beta, theta) over a box of log-stiffnesses theta, not to first order
around the nominal: its network takes theta as inputs. Each design snapshot gives u / d's PCA coefficients c, and every
few snapshots also S_i / d's, the coefficients of dc / dtheta_i (S_i = du / dtheta_i, fem_offline.fe.sensitivity).
So the loss holds both,

    L(W) = mean_s |c_net(x_s) - c_s|^2  +  sum_i lambda_i^2 mean_{s with S} |dc_net / dtheta_i (x_s) - c'_si|^2,

and the model's sensitivities are its own Jacobian, which the ONNX graph computes in closed form (material_graph.py).
lambda_i is tissue i's theta_rms over the box (materials.theta_rms): an error e in S_i moves u by about theta e over
the box, so both terms are mean squared errors of u.

One hidden tanh layer: h = tanh(x W1 + b1), c = [h, 1] W2, so dc / dx_j = ((1 - h^2) * W1[j]) W2, linear in W2 like
c itself. As in network.train (variable projection), W2 is the least-squares solve of both terms for the hidden
weights, and L-BFGS moves only W1, b1 on the reduced loss.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import torch

from .network import Mlp, Scaling, lbfgs_with_restarts

log = logging.getLogger(__name__)


def _features(hidden: torch.nn.Module, x: torch.Tensor, grad_rows: torch.Tensor, grad_columns: list[int]):
    """([h, 1] (n, w + 1), per derivative column j its rows [(1 - h^2) W1[j], 0] (n_grad, w + 1))."""
    linear = hidden[0]
    h = torch.tanh(linear(x))
    ones = torch.ones(len(h), 1, dtype=h.dtype)
    slope = 1.0 - h[grad_rows] ** 2
    zeros = torch.zeros(len(slope), 1, dtype=h.dtype)
    return torch.cat([h, ones], dim=1), [torch.cat([slope * linear.weight[:, j], zeros], dim=1) for j in grad_columns]


def _solve(h, dh, y, dy, weights):
    """W2 (w + 1, r) minimising mean |h W - y|^2 + sum_j weights_j mean |dh_j W - dy_j|^2 (ridge 1e-12)."""
    a = h.T @ h / len(h)
    b = h.T @ y / len(h)
    for d, t, wj in zip(dh, dy, weights):
        if len(d):
            a = a + wj * d.T @ d / len(d)
            b = b + wj * d.T @ t / len(d)
    ridge = 1e-12 * torch.trace(a) * torch.eye(len(a), dtype=a.dtype)
    return torch.linalg.solve(a + ridge, b)


def _loss(h, dh, y, dy, weights, w2):
    loss = ((h @ w2 - y) ** 2).sum(dim=1).mean()
    for d, t, wj in zip(dh, dy, weights):
        if len(d):
            loss = loss + wj * ((d @ w2 - t) ** 2).sum(dim=1).mean()
    return loss


def train_sobolev(inputs: np.ndarray, coefficients: np.ndarray, *, grad_rows: np.ndarray, grad_columns: list[int],
                  grad_targets: list[np.ndarray], grad_weights: np.ndarray, width: int = 60, max_iterations: int = 1000,
                  seed: int = 0, progress=None) -> tuple[Mlp, Scaling, dict]:
    """Fit a one-hidden-layer MLP to coefficients (n, r) at inputs (n, p) and, at the rows `grad_rows` (bool (n,)),
    to the derivatives grad_targets[k] (n_grad, r) = dc / d inputs[:, grad_columns[k]], weighted grad_weights[k]
    (module docstring). Float64, full batch, deterministic given the seed."""
    torch.manual_seed(seed)
    scaling = Scaling.fit(inputs, coefficients)
    x = torch.from_numpy((inputs - scaling.input_center) / scaling.input_scale)
    sqrt_weight = scaling.coef_scale / np.sqrt((scaling.coef_scale**2).sum())
    y = torch.from_numpy((coefficients - scaling.coef_mean) / scaling.coef_scale * sqrt_weight)
    # d/dx_n = input_scale d/dx: the targets in the network's normalised inputs and outputs
    dy = [torch.from_numpy(t * scaling.input_scale[j] / scaling.coef_scale * sqrt_weight)
          for j, t in zip(grad_columns, grad_targets)]
    weights = [float(w) / scaling.input_scale[j] ** 2 for j, w in zip(grad_columns, grad_weights)]
    rows = torch.from_numpy(np.flatnonzero(grad_rows))
    net = Mlp(coefficients.shape[1], width, depth=1, n_in=inputs.shape[1]).double()
    hidden = net.layers[:-1]

    def reduced() -> torch.Tensor:
        h, dh = _features(hidden, x, rows, grad_columns)
        return _loss(h, dh, y, dy, weights, _solve(h, dh, y, dy, weights))

    t0 = time.perf_counter()
    done, restarts = lbfgs_with_restarts(hidden.parameters(), reduced, max_iterations, progress)
    with torch.no_grad():
        h, dh = _features(hidden, x, rows, grad_columns)
        w2 = _solve(h, dh, y, dy, weights)
        loss = float(_loss(h, dh, y, dy, weights, w2))
        value_loss = float(((h @ w2 - y) ** 2).sum(dim=1).mean())
        w2 = w2 / torch.from_numpy(sqrt_weight)
        net.layers[-1].weight.copy_(w2[:-1].T)
        net.layers[-1].bias.copy_(w2[-1])
    info = {"iterations": int(done), "restarts": restarts, "final_loss": loss, "value_loss": value_loss,
            "seconds": time.perf_counter() - t0, "seed": seed}
    log.info("trained %d iterations, loss %.3e (values %.3e), %.1f s", done, loss, value_loss, info["seconds"])
    return net, scaling, info


def jacobian(layers, x: np.ndarray, columns: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Float64 (c (n, r), dc / dx_j (n, len(columns), r)) of folded layers [(W1, b1), (W2, b2)] at raw inputs x."""
    (w1, b1), (w2, b2) = layers
    h = np.tanh(np.asarray(x, dtype=np.float64) @ w1 + b1)
    slope = 1.0 - h**2
    return h @ w2 + b2, np.einsum("nw,jw,wr->njr", slope, w1[columns], w2)
