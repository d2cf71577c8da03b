"""Scatter element vectors and matrices into global arrays through a precomputed CSR pattern."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp


@dataclass(frozen=True)
class Pattern:
    """CSR structure of the free-free block and where each element entry lands in it.

    edofs (n_tets, 30): global DOF 3 * node + comp of each element entry (a, i).
    slot (n_tets * 900,): index into the free-free CSR data, or nnz (a dump slot) when the
    row or column is not free.
    """

    n_dofs: int
    edofs: np.ndarray
    free: np.ndarray  # (n_free,) global DOF ids
    indptr: np.ndarray
    indices: np.ndarray
    slot: np.ndarray

    @property
    def nnz(self) -> int:
        return self.indices.size


def element_dofs(tets: np.ndarray) -> np.ndarray:
    """(n_tets, 30) global DOFs ordered (node a, component i)."""
    return (3 * tets[:, :, None] + np.arange(3)).reshape(len(tets), 30)


def build_pattern(tets: np.ndarray, n_nodes: int, free: np.ndarray) -> Pattern:
    """Sparsity of K_II, the matrix on free DOFs, for the given tets (one-off; O(n_tets * 900) ints)."""
    edofs = element_dofs(tets)
    n_dofs = 3 * n_nodes
    local = np.full(n_dofs, -1, dtype=np.int64)
    local[free] = np.arange(free.size)
    le = local[edofs]  # (n_tets, 30)
    rows = np.broadcast_to(le[:, :, None], (len(tets), 30, 30)).ravel()
    cols = np.broadcast_to(le[:, None, :], (len(tets), 30, 30)).ravel()
    keep = (rows >= 0) & (cols >= 0)
    keys = rows[keep] * free.size + cols[keep]
    unique, inverse = np.unique(keys, return_inverse=True)
    slot = np.full(rows.size, unique.size, dtype=np.int64)
    slot[keep] = inverse.ravel()
    r, c = np.divmod(unique, free.size)
    indptr = np.zeros(free.size + 1, dtype=np.int64)
    np.cumsum(np.bincount(r, minlength=free.size), out=indptr[1:])
    return Pattern(n_dofs, edofs, free, indptr, c.astype(np.int32), slot)


def assemble_matrix(pattern: Pattern, Ke: np.ndarray) -> sp.csr_matrix:
    """K_II from element matrices (n_tets, 10, 3, 10, 3)."""
    data = np.bincount(pattern.slot, weights=Ke.ravel(), minlength=pattern.nnz + 1)[:-1]
    n = pattern.free.size
    return sp.csr_matrix((data, pattern.indices, pattern.indptr), shape=(n, n))


def assemble_vector(pattern: Pattern, fe: np.ndarray) -> np.ndarray:
    """Global vector (n_dofs,) from element vectors (n_tets, 10, 3)."""
    return np.bincount(pattern.edofs.ravel(), weights=fe.ravel(), minlength=pattern.n_dofs)


def apply_matrix(pattern: Pattern, Ke: np.ndarray, u: np.ndarray) -> np.ndarray:
    """K u on all DOFs, element by element (used for the Dirichlet coupling K_ID du_D)."""
    ue = u[pattern.edofs].reshape(-1, 10, 3)
    fe = np.einsum("eaibk,ebk->eai", Ke, ue, optimize=True)
    return assemble_vector(pattern, fe)
