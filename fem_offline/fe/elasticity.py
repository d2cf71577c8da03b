"""Element kernels for small-strain and neo-Hookean elasticity, vectorised over tets and quadrature points.

Shapes: G (n_tets, n_qp, 10, 3) reference gradients of the P2 shape functions, W (n_tets, n_qp)
quadrature weights times |det J|, Ue (n_tets, 10, 3) element displacements. Element matrices are
(n_tets, 10, 3, 10, 3) = (tet, node a, comp i, node b, comp k). Stresses in kPa, lengths in mm.

Why not scikit-fem's BilinearForm: on a 60k-tet mesh it took 17.8 s and 3.3 GB where these
einsums over scikit-fem's own basis gradients take 1.1 s (`python -m bench fem` prints both
on the default mesh). scikit-fem still provides the mesh, the P2 basis and the quadrature.

Neo-Hookean (compressible), with the small-strain mu, lambda of each tissue:
    W(F) = mu/2 (tr C - 3) - mu ln J + lambda/2 (ln J)^2
    P    = mu (F - F^-T) + lambda ln J F^-T
It is polyconvex and its energy -> infinity as J -> 0, so unlike St Venant-Kirchhoff it does not
soften and lose stability in compression under the guide.

Mean dilatation (solver.volumetric = "mean_dilatation"; `md` below): the volumetric term is taken
at each tet's volume ratio theta_e = v_e / V_e = (1/V_e) int_e J dX, not point by point:
    Pi_vol = sum_e V_e lambda/2 (ln theta_e)^2       (small strain: V_e lambda/2 (mean tr eps)^2)
    P      = mu (F - F^-T) + p_e J F^-T,  p_e = lambda ln(theta_e) / theta_e
This is the P2/P0 element with its constant pressure condensed per tet. At nu = 0.495
(lambda / mu = 99) the pointwise P2 element is too stiff in volume change on coarse meshes
(volumetric locking, `python -m studies locking-check`); one constraint per tet instead of one per
quadrature point relieves it. The shear terms (mu) stay pointwise.

Taylor-Hood (solver.volumetric = "taylor_hood"; `pressure` below): the volumetric stress is a given
pressure p at each quadrature point, interpolated from a P1 field (fem_offline/fe/mixed.py), and the
kernels here give the shear part and p's terms: P = mu (F - F^-T) + p F^-T, sigma = 2 mu eps + p I.
"""

from __future__ import annotations

import numpy as np


def displacement_gradient(G: np.ndarray, Ue: np.ndarray) -> np.ndarray:
    """H_ij = sum_a u_ai dN_a/dX_j at every quadrature point; (n_tets, n_qp, 3, 3)."""
    return np.einsum("eai,eqaj->eqij", Ue, G, optimize=True)


def tet_mean(W, x) -> tuple[np.ndarray, np.ndarray]:
    """((1/V_e) int_e x dX, V_e) per tet from values x (n_tets, n_qp) at the quadrature points."""
    V = W.sum(axis=1)
    return np.einsum("eq,eq->e", W, x) / V, V


def linear_stiffness(G, W, mu, lam, md: bool = False) -> np.ndarray:
    """K_e = int lam (div) (div) + mu (grad u : grad v + grad u : grad v^T); with `md` the lam term is
    lam / V_e (int div)(int div)."""
    GW = G * W[:, :, None, None]
    M = np.einsum("eqaj,eqbj->eab", GW, G, optimize=True)
    if md:
        b = GW.sum(axis=1)  # (e, 10, 3): int dN_a/dX_i
        K = (lam / W.sum(axis=1))[:, None, None, None, None] * np.einsum("eai,ebk->eaibk", b, b)
    else:
        K = lam[:, None, None, None, None] * np.einsum("eqai,eqbk->eaibk", GW, G, optimize=True)
    K += mu[:, None, None, None, None] * np.einsum("eqak,eqbi->eaibk", GW, G, optimize=True)
    K += (mu[:, None, None] * M)[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
    return K


def linear_stress(H, mu, lam, W=None, pressure=None) -> np.ndarray:
    """sigma = lam tr(eps) I + 2 mu eps, eps = sym(H); with W (mean dilatation) tr(eps) is each tet's mean;
    with `pressure` (n_tets, n_qp) sigma = 2 mu eps + p I (Taylor-Hood)."""
    if pressure is None:
        tr = np.trace(H, axis1=2, axis2=3)
        if W is not None:
            tr = np.broadcast_to(tet_mean(W, tr)[0][:, None], tr.shape)
        pressure = lam[:, None] * tr
    sigma = mu[:, None, None, None] * (H + H.transpose(0, 1, 3, 2))
    sigma += pressure[:, :, None, None] * np.eye(3)
    return sigma


def neo_hookean_stress(H, mu, lam, W=None, pressure=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First Piola-Kirchhoff stress P, F^-1 and J = det F; J <= 0 gives NaN in P (caller checks).
    With W, the volumetric stress is the mean dilatation's p_e J F^-T; with `pressure`, a function of
    J giving p at each quadrature point (Taylor-Hood), it is p F^-T."""
    F = H + np.eye(3)
    J = np.linalg.det(F)
    Finv = np.linalg.inv(F)
    with np.errstate(invalid="ignore", divide="ignore"):
        if pressure is not None:
            vol = pressure(J)
        elif W is None:
            vol = lam[:, None] * np.log(J)
        else:
            theta = tet_mean(W, J)[0]
            vol = (lam * np.log(theta) / theta)[:, None] * J
    FinvT = Finv.transpose(0, 1, 3, 2)
    P = mu[:, None, None, None] * (F - FinvT) + vol[:, :, None, None] * FinvT
    return P, Finv, J


def log_det(H) -> np.ndarray:
    """ln det(I + H) without round-off at small H: det(I + H) - 1 = tr H + i2(H) + det H, then log1p."""
    trH = np.trace(H, axis1=2, axis2=3)
    i2 = 0.5 * (trH**2 - np.einsum("eqij,eqji->eq", H, H))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.log1p(trH + i2 + np.linalg.det(H))


def neo_hookean_energy(H, J, W, mu, lam, md: bool = False) -> float:
    """Stored energy sum_q W(F) dx (kPa mm^3 = mJ), given J = det F from the stress pass; +inf if any J <= 0.
    With `md` the volumetric part is sum_e V_e lam/2 (ln theta_e)^2."""
    if not J.min() > 0:
        return np.inf
    lnJ, trH = log_det(H), np.trace(H, axis1=2, axis2=3)
    # W = mu/2 (tr C - 3) - mu ln J with tr C - 3 = 2 tr H + H : H, written so that no O(1) terms cancel:
    # mu (tr H - ln J) + mu/2 H : H. The textbook form loses eps * mu per point to round-off, which in a
    # stiff tissue (bone at 1.7e5 x fat) swamped the energy decrease of Newton's last steps (line search).
    w = mu[:, None] * (trH - lnJ) + 0.5 * mu[:, None] * np.einsum("eqij,eqij->eq", H, H)
    if not md:
        return float(np.sum((w + 0.5 * lam[:, None] * lnJ**2) * W))
    theta, V = tet_mean(W, J)
    return float(np.sum(w * W) + np.sum(0.5 * lam * V * np.log(theta) ** 2))


def linear_energy(H, W, mu, lam, md: bool = False) -> float:
    """Stored energy 1/2 sigma : eps summed over quadrature points (with `md`, tr eps is each tet's mean)."""
    eps = 0.5 * (H + H.transpose(0, 1, 3, 2))
    tr = np.trace(eps, axis1=2, axis2=3)
    w = mu[:, None] * np.einsum("eqij,eqij->eq", eps, eps)
    if not md:
        return float(np.sum((w + 0.5 * lam[:, None] * tr**2) * W))
    mean_tr, V = tet_mean(W, tr)
    return float(np.sum(w * W) + np.sum(0.5 * lam * V * mean_tr**2))


def neo_hookean_tangent(G, W, Finv, J, mu, lam, md: bool = False, pressure=None) -> np.ndarray:
    """K_e = int G_aj A_ijkl G_bl, A = dP/dF = mu d_ik d_jl + (mu - lam ln J) Fi_li Fi_jk + lam Fi_ji Fi_lk.

    With `md` (g = G F^-1, b_e = int J g dX, p_e = lam ln(theta_e) / theta_e):
        K_e = lam (1 - ln theta_e) / (theta_e^2 V_e) b_e b_e^T + int p_e J g_ai g_bk
              + int (mu - p_e J) g_ak g_bi + mu M_ab d_ik.

    With `pressure` p (n_tets, n_qp), at fixed p (Taylor-Hood; the pressure's own coupling is mixed.py's):
        K_e = int (mu - p) g_ak g_bi + mu M_ab d_ik.

    Each term is an outer product summed over quadrature points, written as batched matmuls over
    (element, 30 x q) blocks, and summed in place into the first: no temporary as large as K, which
    on 20k tets (145 MB per copy) cost more than the products (0.43 s -> 0.10 s a call on the
    patient_medium mesh, 0.049 -> 0.043 s on the default mesh; bit-identical).
    """
    g = np.matmul(G, Finv)  # (e, q, 10, 3) spatial gradients g_ak = G_aj Fi_jk
    e, q = g.shape[:2]
    gW = g * W[:, :, None, None]
    flat = g.reshape(e, q, 30)
    if pressure is not None:
        c = mu[:, None] - pressure
        K = np.zeros((e, 30, 30))
    elif md:
        theta, V = tet_mean(W, J)
        pJ = (lam * np.log(theta) / theta)[:, None] * J  # (e, q)
        c = mu[:, None] - pJ
        K = np.matmul((gW * pJ[:, :, None, None]).reshape(e, q, 30).transpose(0, 2, 1), flat)
        b = np.einsum("eq,eqx->ex", W * J, flat)  # (e, 30)
        K += (lam * (1.0 - np.log(theta)) / (theta**2 * V))[:, None, None] * (b[:, :, None] * b[:, None, :])
    else:
        c = mu[:, None] - lam[:, None] * np.log(J)
        # K[e, (a,i), (b,k)] = lam sum_q W g_ai g_bk + K1[e, (a,k), (b,i)], K1 = sum_q c W g_ak g_bi
        K = np.matmul(gW.reshape(e, q, 30).transpose(0, 2, 1), flat)
        K *= lam[:, None, None]
    K1 = np.matmul((gW * c[:, :, None, None]).reshape(e, q, 30).transpose(0, 2, 1), flat)
    K = K.reshape(e, 10, 3, 10, 3)
    K += K1.reshape(e, 10, 3, 10, 3).transpose(0, 1, 4, 3, 2)
    del K1
    GW = (G * W[:, :, None, None]).transpose(0, 2, 1, 3).reshape(e, 10, 3 * q)
    M = np.matmul(GW, G.transpose(0, 2, 1, 3).reshape(e, 10, 3 * q).transpose(0, 2, 1))  # (e, 10, 10)
    M *= mu[:, None, None]
    for i in range(3):
        K[:, :, i, :, i] += M  # mu M_ab d_ik
    return K


def internal_force(G, W, P) -> np.ndarray:
    """f_ai = int P_ij dN_a/dX_j; (n_tets, 10, 3)."""
    return np.einsum("eqij,eqaj->eai", P * W[:, :, None, None], G, optimize=True)
