"""The Taylor-Hood element (solver.volumetric = "taylor_hood"): P2 displacement, P1 pressure.

The volumetric energy lambda/2 (ln J)^2 (small strain: lambda/2 (tr eps)^2) is replaced by its mixed
form with a pressure p, continuous and linear on the tets of each tissue (a pressure unknown per
tet corner and tissue, so it may jump where lambda does, at a tissue boundary):

    Pi(u, p) = int psi_shear(F) dX + int p g(u) dX - int p^2 / (2 lambda) dX,    g = ln J  (or tr eps)
    psi_shear = mu/2 (tr C - 3) - mu ln J                                          (or mu eps : eps)

Stationarity in p makes p the L2 projection of lambda g onto that P1 space: M p = b(u), with
M_ab = int N_a N_b / lambda and b_a = int N_a g. Eliminating p gives a displacement energy

    Pi(u) = int psi_shear dX + 1/2 b(u)^T M^-1 b(u)

whose force is P = mu (F - F^-T) + p F^-T at each quadrature point (p interpolated from the corners)
and whose Hessian is K_shear(p) + G^T M^-1 G, G = db/du (G_a,(n,i) = int N_a dN_n/dx_i). M^-1 is
dense, so that Hessian is never formed: Newton solves the sparse saddle-point system

    [ K_shear(p)  G^T ] [du]   [rhs]
    [ G          -M   ] [dp] = [ 0 ]

whose du is the reduced Newton step (block elimination of dp), factorised as symmetric indefinite
(PARDISO mtype -2), and CG runs on the reduced Hessian as a LinearOperator. So Newton, its line
search on the energy Pi(u), the contact terms and det F > 0 are as for the displacement elements
(newton.py).

Why: with lambda / mu = 99 (nu = 0.495) the pointwise P2 element is too stiff in volume change on
the study's meshes (volumetric locking, `python -m studies locking-check`), and the mean-dilatation P2/P0
element is too soft (its P0 pressure converges at first order). Taylor-Hood P2/P1 is inf-sup stable
with one pressure unknown per vertex (about one per 6 tets), so it neither locks nor loses the P2
element's order.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

from fem_offline.fe.linsolve import Factor, PyPardisoSolver, _Pardiso, _point_pypardiso_at_mkl

# Newton's saddle-point factors are float32 (PARDISO iparm 28; newton.SINGLE_FACTORS): half the memory traffic of
# a factorisation and a back-substitution. A fresh factor's step is refined on the float64 reduced Hessian
# (SaddleFactor.solve), and CG on that operator to 1e-2 takes them as a preconditioner; a step the line search
# rejects is redone with float64 factors (newton.py). Measured on default.toml's mesh, 1 thread, 10 mm path at
# 0 deg, first five 0.25 mm steps: 99 s -> 73 s (9,030 tets), 25 s on 5,092 tets.


@dataclass(frozen=True)
class Pressure:
    """The P1 pressure space on the assembled tets and its constant mass matrix M = int N N / lambda."""

    n: int  # pressure unknowns
    index: np.ndarray  # (n_tets, 4) pressure unknown of each tet corner
    N: np.ndarray  # (n_tets, n_qp, 4) P1 shape values at the quadrature points
    mass: sp.csr_matrix  # (n, n)
    mass_factor: Factor
    rows: np.ndarray  # (n_tets * 4 * 30,) row of each coupling entry (tet, corner, DOF)
    cols: np.ndarray  # its column: the global DOF

    def project(self, W: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """b = int N g, the pressure p = M^-1 b and p at every quadrature point (n_tets, n_qp), for g (n_tets, n_qp)."""
        b = np.bincount(self.index.ravel(), weights=np.einsum("eq,eqa->ea", W * g, self.N).ravel(), minlength=self.n)
        p = self.mass_factor.solve(b)
        return b, p, np.einsum("eqa,ea->eq", self.N, p[self.index])

    def coupling(self, W: np.ndarray, grad: np.ndarray, n_dofs: int) -> sp.csr_matrix:
        """G = db/du (n, n_dofs): int N_a dN_n/dx_i, from the spatial P2 gradients (n_tets, n_qp, 10, 3)."""
        Ge = np.einsum("eq,eqa,eqx->eax", W, self.N, grad.reshape(*grad.shape[:2], 30), optimize=True)
        return sp.csr_matrix((Ge.ravel(), (self.rows, self.cols)), shape=(self.n, n_dofs))


def pressure_space(vertices: np.ndarray, N: np.ndarray, W: np.ndarray, tissue: np.ndarray, lam: np.ndarray,
                   edofs: np.ndarray) -> Pressure:
    """The pressure space of tets with corner nodes `vertices` (n_tets, 4), P1 values N (n_tets, n_qp, 4),
    weights W, tissue ids, lambda per tet and element DOFs edofs (n_tets, 30)."""
    keys = vertices.astype(np.int64) * (int(tissue.max()) + 1) + tissue[:, None]
    _, index = np.unique(keys.ravel(), return_inverse=True)
    index = index.reshape(vertices.shape)
    n = int(index.max()) + 1
    Me = np.einsum("eq,eqa,eqb->eab", W / lam[:, None], N, N)
    rows = np.broadcast_to(index[:, :, None], (*index.shape, 4))
    cols = np.broadcast_to(index[:, None, :], (*index.shape, 4))
    mass = sp.csr_matrix((Me.ravel(), (rows.ravel(), cols.ravel())), shape=(n, n))
    rows = np.broadcast_to(index[:, :, None], (*index.shape, 30)).ravel()
    cols = np.broadcast_to(edofs[:, None, :], (len(edofs), 4, 30)).ravel()
    return Pressure(n, index, np.ascontiguousarray(N), mass, Factor(mass), rows, cols)


class Tangent(LinearOperator):
    """The reduced Hessian K + G^T M^-1 G on the free DOFs, as an operator; `factorise()` gives its inverse
    through the saddle-point matrix."""

    def __init__(self, K: sp.csr_matrix, G: sp.csr_matrix, pressure: Pressure):
        super().__init__(np.float64, K.shape)
        self.K, self.G, self.pressure = K, G, pressure

    def _matvec(self, v):
        v = np.ravel(v)
        return self.K @ v + self.G.T @ self.pressure.mass_factor.solve(self.G @ v)

    def saddle(self) -> sp.csr_matrix:
        return sp.bmat([[self.K, self.G.T], [self.G, -self.pressure.mass]], format="csr")

    def factorise(self, float32: bool = False) -> SaddleFactor:
        return SaddleFactor(self, float32=float32)


def reduced_product(pressure: Pressure, G: sp.csr_matrix, v: np.ndarray) -> np.ndarray:
    """G^T M^-1 G v on all DOFs: the pressure's part of the Hessian times v (the K_ID du_D coupling)."""
    return G.T @ pressure.mass_factor.solve(G @ v)


class SaddleFactor:
    """The saddle-point matrix [[K, G^T], [G, -M]] factorised as symmetric indefinite (PARDISO mtype -2, float32 or 64,
    with weighted matching for the zero-free but small pressure block); solve(b) = du of [b; 0], the reduced
    Hessian's inverse applied to b. Serves as CG's preconditioner for later tangents, as a Factor does."""

    max_cg = 12
    cg_first = False  # newton.py: a fresh factor's own (refined) solve gives the step, not CG

    def __init__(self, tangent: Tangent, float32: bool = False):
        self.shape, self.n, self.float32 = tangent.shape, tangent.shape[0], float32
        self._tangent = tangent
        A = tangent.saddle()
        if PyPardisoSolver is None:
            from scipy.sparse.linalg import splu

            self._lu = splu(A.tocsc())
            return
        self._A = self._upper(A)
        _point_pypardiso_at_mkl()
        self._pardiso = _Pardiso(self._A, -2, float32, matching=True)

    @staticmethod
    def _upper(A):
        A = sp.triu(A, format="csr")
        A.sort_indices()
        return A

    def _solve(self, b):
        rhs = np.concatenate([b, np.zeros(self._tangent.pressure.n)])
        x = self._lu.solve(rhs) if PyPardisoSolver is None else self._pardiso.solve(rhs)
        return x[: self.n]

    def precondition(self, b):
        return self._solve(np.ravel(b))

    def solve(self, b: np.ndarray, refinements: int = 2) -> np.ndarray:
        """The reduced step, with iterative refinement on the reduced Hessian (the pivots are perturbed)."""
        x = self._solve(b)
        for _ in range(refinements):
            x += self._solve(b - self._tangent @ x)
        return x

    def refactor(self, tangent: Tangent) -> SaddleFactor:
        """Factorise a later tangent, reusing the symbolic analysis (PARDISO phase 22) when the pattern is the same."""
        if PyPardisoSolver is None:
            return SaddleFactor(tangent, float32=self.float32)
        A = self._upper(tangent.saddle())
        if A.nnz != self._A.nnz or not np.array_equal(A.indices, self._A.indices):
            return SaddleFactor(tangent, float32=self.float32)
        self._pardiso.factor(A.data, phase=22)
        self._A, self._tangent = A, tangent
        return self

    def __del__(self):
        if PyPardisoSolver is not None and hasattr(self, "_pardiso"):
            if sys.meta_path is not None:  # not at interpreter shutdown
                self._pardiso.free()
