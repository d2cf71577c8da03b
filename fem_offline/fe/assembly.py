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
    """Sparsity of K_II, the matrix on free DOFs, for the given tets (one-off).

    Works on node pairs (100 per tet) and expands each to its 3 x 3 block of free components
    afterwards: sorting the 900 DOF pairs per tet instead took 40 of 44 s and 14 GB on the
    paper-scale mesh (226k tets).
    """
    n_tets, n_dofs = len(tets), 3 * n_nodes
    local = np.full(n_dofs, -1, dtype=np.int64)
    local[free] = np.arange(free.size)
    is_free = (local >= 0).reshape(n_nodes, 3)
    n_free = is_free.sum(axis=1)  # free components per node
    rank = np.cumsum(is_free, axis=1) - is_free  # index of component j among its node's free ones

    # Node blocks (A, B) that share a tet, in row-major order; `block` maps each tet entry to one.
    pairs = tets[:, :, None].astype(np.int64) * n_nodes + tets[:, None, :]
    keys, block = np.unique(pairs.ravel(), return_inverse=True)
    del pairs
    block_row, block_col = np.divmod(keys, n_nodes)
    width = n_free[block_col]  # free columns each block adds to a row of node A
    row_width = np.bincount(block_row, weights=width, minlength=n_nodes).astype(np.int64)
    ends = np.cumsum(width)
    row_start = np.zeros(n_nodes, dtype=np.int64)
    np.cumsum(row_width[:-1], out=row_start[1:])
    offset = ends - width - row_start[block_row]  # first column of each block within its row

    # Rows: every free DOF (A, i) has the same columns, those of node A's row.
    row_node = free // 3
    indptr = np.zeros(free.size + 1, dtype=np.int64)
    np.cumsum(row_width[row_node], out=indptr[1:])
    block_cols = local[3 * block_col[:, None] + np.arange(3)]  # (n_blocks, 3)
    node_cols = block_cols[block_cols >= 0]  # each node's row of free columns, concatenated
    lengths = np.diff(indptr)
    within = np.arange(indptr[-1]) - np.repeat(indptr[:-1], lengths)
    indices = node_cols[within + np.repeat(row_start[row_node], lengths)].astype(np.int32)

    # Slot of entry (tet, a, i, b, j): indptr[row] + offset[block] + rank of j in node B.
    nnz, never = indices.size, np.iinfo(np.int64).min // 4  # `never` keeps a sum with it negative
    row_dof = local[3 * tets[:, :, None] + np.arange(3)]  # (n_tets, 10, 3)
    row_part = np.where(row_dof >= 0, indptr[np.maximum(row_dof, 0)], never)
    col_part = np.where(is_free[tets], rank[tets], never)  # (n_tets, 10, 3)
    slot = (row_part[:, :, :, None, None] + offset[block].reshape(n_tets, 10, 1, 10, 1)
            + col_part[:, None, None, :, :]).ravel()
    slot[slot < 0] = nnz  # a constrained row or column: the dump slot
    return Pattern(n_dofs, element_dofs(tets), free, indptr, indices, slot)


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
