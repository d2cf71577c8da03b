"""Sparse direct factorisation (MKL PARDISO via pypardiso; SuperLU where MKL is missing)."""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp

log = logging.getLogger(__name__)

try:
    from pypardiso import PyPardisoSolver
except ImportError:  # no MKL on this platform (e.g. aarch64)
    PyPardisoSolver = None


class Factor:
    """A factorised symmetric matrix; `solve(b)` reuses the factors (no re-hash of the matrix).

    PARDISO runs as SPD Cholesky (mtype 2) on the upper triangle and falls back to symmetric
    indefinite (mtype -2) if the tangent has lost definiteness.
    """

    def __init__(self, K: sp.csr_matrix):
        self.shape = K.shape
        if PyPardisoSolver is None:
            from scipy.sparse.linalg import splu

            self._lu = splu(K.tocsc())
            return
        self._A = sp.triu(K, format="csr")
        self._A.sort_indices()
        for mtype in (2, -2):
            self._ps = PyPardisoSolver(mtype=mtype)
            try:
                self._ps.factorize(self._A)
                break
            except Exception as exc:  # PyPardisoError: not positive definite
                log.info("PARDISO mtype %d failed (%s); trying indefinite", mtype, exc)
        else:
            raise np.linalg.LinAlgError("PARDISO could not factorise the tangent")

    def solve(self, b: np.ndarray) -> np.ndarray:
        if PyPardisoSolver is None:
            return self._lu.solve(b)
        self._ps.set_phase(33)
        return self._ps._call_pardiso(self._A, np.asfortranarray(b, dtype=np.float64))

    def __del__(self):
        # pypardiso keeps MKL's factors until told; release them with the last reference.
        if PyPardisoSolver is not None and hasattr(self, "_ps"):
            self._ps.free_memory(everything=True)
