"""Sparse direct factorisation (MKL PARDISO via pypardiso; SuperLU where MKL is missing)."""

from __future__ import annotations

import ctypes
import glob
import logging
import os
import sys
from ctypes.util import find_library
from functools import lru_cache

import numpy as np
import scipy.sparse as sp

log = logging.getLogger(__name__)

# MKL's defaults (iparm(1) = 0) include two steps of iterative refinement per solve, tripling the
# cost of a back-substitution (measured: 64 ms -> 21 ms at 40k DOFs, same residual). Setting any
# iparm needs iparm(1) = 1, and then the rest of MKL's defaults must be given too (1-based).
IPARM = {1: 1, 2: 2, 8: 0, 10: 8, 11: 0, 13: 0, 21: 1}

try:
    from pypardiso import PyPardisoSolver
except ImportError:  # no MKL on this platform (e.g. aarch64)
    PyPardisoSolver = None


@lru_cache(maxsize=1)
def _point_pypardiso_at_mkl() -> None:
    """Find libmkl_rt once, at the first factorisation, and tell pypardiso (PYPARDISO_MKL_RT).

    Where ctypes cannot find the library (a venv), pypardiso walks sys.prefix for it on every
    solver it creates: about 1 s per factorisation. The variable is its only way in; the search
    runs here, not at import, so importing this module leaves the environment alone.
    """
    if "PYPARDISO_MKL_RT" in os.environ or find_library("mkl_rt") is not None:
        return
    hits = sorted(glob.glob(f"{sys.prefix}/[Ll]ib*/**/*mkl_rt*", recursive=True), key=len)
    if hits:
        os.environ["PYPARDISO_MKL_RT"] = hits[0]


class _Pardiso:
    """One MKL PARDISO handle (pypardiso's) on an upper triangle A, in float64 or float32.

    Called directly rather than through pypardiso's solve(): that re-casts the matrix's indices to
    1-based int32 on every call and takes float64 only. float32 factors (iparm(28) = 1) halve what
    a factorisation and a back-substitution move through memory; Newton uses them only to
    precondition CG (newton.py), whose tolerance (1e-2) is far above their 1e-7 relative residual.
    """

    def __init__(self, A: sp.csr_matrix, mtype: int, single: bool, matching: bool = False):
        self._ps = PyPardisoSolver(mtype=mtype)
        for key, value in IPARM.items():
            self._ps.set_iparm(key, value)
        if matching:  # symmetric scaling and weighted matching (iparm 11, 13): MKL's advice for saddle points
            self._ps.set_iparm(11, 1)
            self._ps.set_iparm(13, 1)
        self._ps.set_iparm(28, int(single))
        self.dtype = np.float32 if single else np.float64
        self.mtype, self.n = mtype, A.shape[0]
        self._ia = (A.indptr + 1).astype(np.int32)
        self._ja = (A.indices + 1).astype(np.int32)
        try:
            self.factor(A.data)
        except np.linalg.LinAlgError:
            self.free()  # else MKL keeps the failed factors
            raise

    def _call(self, phase: int, b: np.ndarray) -> np.ndarray:
        ps, error = self._ps, ctypes.c_int32(0)
        x = np.zeros_like(b)
        i32 = ctypes.POINTER(ctypes.c_int32)
        ps._mkl_pardiso(
            ps.pt.ctypes.data_as(ctypes.POINTER(ps._pt_type[0])), ctypes.byref(ctypes.c_int32(1)),
            ctypes.byref(ctypes.c_int32(1)), ctypes.byref(ctypes.c_int32(self.mtype)),
            ctypes.byref(ctypes.c_int32(phase)),
            ctypes.byref(ctypes.c_int32(self.n)), self._a.ctypes.data_as(ctypes.c_void_p), self._ia.ctypes.data_as(i32),
            self._ja.ctypes.data_as(i32), ps.perm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(1)),
            ps.iparm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(0)), b.ctypes.data_as(ctypes.c_void_p),
            x.ctypes.data_as(ctypes.c_void_p), ctypes.byref(error))
        if error.value != 0:
            raise np.linalg.LinAlgError(f"PARDISO error {error.value} in phase {phase}")
        return x

    def factor(self, data: np.ndarray, phase: int = 12) -> None:
        """Analyse and factorise (phase 12), or refactorise with the analysis kept (phase 22)."""
        self._a = np.ascontiguousarray(data, dtype=self.dtype)
        self._call(phase, np.zeros(self.n, self.dtype))

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self._call(33, np.ascontiguousarray(b, dtype=self.dtype)).astype(np.float64, copy=False)

    def free(self) -> None:
        self._ps.free_memory(everything=True)


class Factor:
    """A factorised symmetric matrix; `solve(b)` reuses the factors (no re-hash of the matrix).

    PARDISO runs as SPD Cholesky (mtype 2) on the upper triangle and falls back to symmetric
    indefinite (mtype -2, in float64) if the tangent has lost definiteness. As a preconditioner for
    a later tangent (modified Newton) it serves while CG needs at most `max_cg` iterations.
    `float32`: float32 factors, for a preconditioner (a solve is then accurate to about 1e-7), so a fresh
    factor's Newton step also goes through CG (`cg_first`).
    """

    max_cg = 12

    def __init__(self, K: sp.csr_matrix, *, float32: bool = False):
        self.shape, self.float32 = K.shape, float32
        if PyPardisoSolver is None:
            from scipy.sparse.linalg import splu

            self._lu = splu(K.tocsc())
            return
        self._A = sp.triu(K, format="csr")
        self._A.sort_indices()
        _point_pypardiso_at_mkl()
        for mtype, in_single in ((2, float32), (-2, False)):
            try:
                self._pardiso = _Pardiso(self._A, mtype, in_single)
                break
            except np.linalg.LinAlgError as exc:  # not positive definite
                log.info("PARDISO mtype %d failed (%s); trying indefinite", mtype, exc)
        else:
            raise np.linalg.LinAlgError("PARDISO could not factorise the tangent")

    def refactor(self, K: sp.csr_matrix) -> Factor:
        """Factorise a matrix of the same sparsity, reusing the symbolic analysis (PARDISO phase 22).

        Saves the reordering, 0.25 of 1.25 s per factorisation on the default mesh. Falls back to a
        fresh Factor when the pattern differs or the matrix is no longer positive definite.
        """
        if PyPardisoSolver is None or self._pardiso.mtype != 2:
            return Factor(K, float32=self.float32)
        A = sp.triu(K, format="csr")
        A.sort_indices()
        if A.nnz != self._A.nnz or not np.array_equal(A.indices, self._A.indices):
            return Factor(K, float32=self.float32)
        try:
            self._pardiso.factor(A.data, phase=22)
        except np.linalg.LinAlgError as exc:  # lost definiteness
            log.info("PARDISO phase 22 failed (%s); full factorisation", exc)
            return Factor(K, float32=self.float32)
        self._A = A
        return self

    @property
    def cg_first(self) -> bool:
        return self.float32

    def solve(self, b: np.ndarray) -> np.ndarray:
        if PyPardisoSolver is None:
            return self._lu.solve(b)
        return self._pardiso.solve(b)

    precondition = solve

    def __del__(self):
        # pypardiso keeps MKL's factors until told; release them with the last reference. Not while
        # the interpreter shuts down (sys.meta_path is None): pypardiso's release imports then fail,
        # and the process's exit frees the memory anyway.
        if PyPardisoSolver is not None and hasattr(self, "_pardiso") and sys.meta_path is not None:
            self._pardiso.free()


# Above this many unknowns PARDISO's factors outgrow 24 GB: at 910,980 (the paper-scale phantom,
# 225,938 P2 tets) the in-core factorisation was killed at 17.5 GB resident, single-precision
# factors hit a zero pivot (nu = 0.495) and out-of-core mode could not open its files.
AMG_MIN_DOFS = 400_000


def rigid_body_modes(nodes: np.ndarray) -> np.ndarray:
    """The 6 rigid-body displacement fields (3 n_nodes, 6): elasticity's near-nullspace for AMG."""
    x, y, z = nodes.T
    B = np.zeros((3 * len(nodes), 6))
    B[0::3, 0] = B[1::3, 1] = B[2::3, 2] = 1.0
    B[0::3, 3], B[1::3, 3] = -y, x  # rotation about z
    B[1::3, 4], B[2::3, 4] = -z, y  # about x
    B[0::3, 5], B[2::3, 5] = z, -x  # about y
    return B


class AmgSolve:
    """K^-1 b by conjugate gradients preconditioned with smoothed-aggregation AMG (pyamg).

    For SPD systems too large to factorise here. The aggregates carry the rigid-body modes, the
    smoother is symmetric Gauss-Seidel (a free set that splits nodes rules out 3x3 blocks).
    Measured on the paper-scale linear problem (910,980 unknowns, 76.4M nonzeros, nu = 0.495):
    setup 22-27 s; for the guide's load 6 CG iterations to 1e-2, 45 to 1e-4 and 151 to 1e-8,
    about 0.85 s each (one product with K alone takes 0.054 s); on the default mesh it matches
    PARDISO to 4e-6 mm. Stronger aggregation (theta 0.1) halved the iterations to 1e-4 but
    tripled the operator complexity and the setup time (72 s); theta 0.25 did not fit in 24 GB.

    In Newton the hierarchy of one tangent preconditions the later ones while CG needs at most
    `max_cg` iterations, as a Factor does. A fresh hierarchy did not cut the count there (56
    iterations to 1e-2 after a rebuild, about 45 before), so the bar is high.
    """

    max_cg = 150
    float32 = cg_first = False  # CG to rtol is its solve

    def __init__(self, K: sp.csr_matrix, near_nullspace: np.ndarray, rtol: float = 1e-9):
        import pyamg

        self.shape, self.rtol, self.iterations = K.shape, rtol, []
        self._K, self._B = K.tocsr(), near_nullspace
        smoother = ("gauss_seidel", {"sweep": "symmetric"})
        self._ml = pyamg.smoothed_aggregation_solver(
            self._K, B=near_nullspace, symmetry="hermitian", strength=("symmetric", {"theta": 0.0}),
            smooth=("jacobi", {"omega": 4.0 / 3.0, "degree": 1}), presmoother=smoother, postsmoother=smoother,
            max_coarse=2000)
        self._M = self._ml.aspreconditioner(cycle="V")

    def precondition(self, b: np.ndarray) -> np.ndarray:
        """One V-cycle."""
        return self._M @ b

    def refactor(self, K: sp.csr_matrix) -> AmgSolve:
        return AmgSolve(K, self._B, self.rtol)

    def solve(self, b: np.ndarray) -> np.ndarray:
        from scipy.sparse.linalg import cg

        count = [0]
        x, info = cg(self._K, b, rtol=self.rtol, maxiter=5000, M=self._M,
                     callback=lambda _: count.__setitem__(0, count[0] + 1))
        self.iterations.append(count[0])
        if info != 0:
            raise np.linalg.LinAlgError(f"AMG-preconditioned CG did not reach rtol {self.rtol} "
                                        f"in {count[0]} iterations")
        log.info("AMG-CG: %d iterations", count[0])
        return x


def factorise(K: sp.csr_matrix, near_nullspace: np.ndarray | None = None, amg_min_dofs: int | None = None,
              rtol: float = 1e-9, float32: bool = False):
    """A solver for K: PARDISO's factors (float32 ones if `float32`), or AMG-CG to `rtol` when K is too
    large to factorise (and B is given)."""
    if near_nullspace is not None and K.shape[0] >= (AMG_MIN_DOFS if amg_min_dofs is None else amg_min_dofs):
        return AmgSolve(K, near_nullspace, rtol)
    return Factor(K, float32=float32)
