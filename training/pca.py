"""PCA of snapshot displacements by the method of snapshots, in float64.

With X the centred data (n_snapshots x 3 n_nodes), the Gram matrix G = X X^T is only
n_snapshots^2 (840^2), so the fit stays in memory at paper scale (3 n_nodes ~ 1e6) where a
covariance matrix could not. G = U S^2 U^T gives the principal directions V = X^T U S^-1.
"""

from __future__ import annotations

from dataclasses import dataclass

import logging

import numpy as np

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Pca:
    mean: np.ndarray  # (3 n_nodes,)
    basis: np.ndarray  # (rank, 3 n_nodes), orthonormal rows
    singular_values: np.ndarray  # (n_snapshots,) all of them, to report energy at any rank
    n_primary: int | None = None  # fit_pca_with_extra: the first n_primary rows are the primary rows' own modes

    @property
    def rank(self) -> int:
        return len(self.basis)

    @property
    def energy(self) -> float:
        """Fraction of the centred (primary) data's variance that its own modes capture."""
        s2 = self.singular_values**2
        return float(s2[: self.n_primary or self.rank].sum() / s2.sum())

    def encode(self, x: np.ndarray) -> np.ndarray:
        return (x - self.mean) @ self.basis.T  # (n, rank)

    def decode(self, coefficients: np.ndarray) -> np.ndarray:
        return self.mean + coefficients @ self.basis  # (n, 3 n_nodes)


def _modes(x: np.ndarray, rank: int) -> tuple[np.ndarray, np.ndarray]:
    """(basis (rank, n_cols) orthonormal rows, all singular values) of rows x by the method of snapshots."""
    gram = x @ x.T  # (n, n)
    eigval, eigvec = np.linalg.eigh(gram)
    order = np.argsort(eigval)[::-1]
    eigval, eigvec = np.clip(eigval[order], 0.0, None), eigvec[:, order]
    s = np.sqrt(eigval)
    numerical = int((s > 1e-9 * s[0]).sum())  # a linear sweep's f = u / d spans 2 modes, whatever rank is asked
    if rank > numerical:
        log.warning("rank %d asked for, the snapshots span %d modes: using %d", rank, numerical, numerical)
        rank = numerical
    basis = (eigvec[:, :rank] / s[:rank]).T @ x  # (rank, n_cols)
    return _orthonormal(basis), s


def _orthonormal(basis: np.ndarray) -> np.ndarray:
    """One Gram-Schmidt pass (QR), signs kept: removes the round-off the S^-1 scaling leaves in weak modes."""
    q, r = np.linalg.qr(basis.T)
    return (q * np.sign(np.diag(r))).T


def fit_pca_with_extra(x: np.ndarray, extra: np.ndarray, rank: int, extra_rank: int) -> Pca:
    """The leading `rank` modes of the primary rows x, then `extra_rank` modes of what they leave of the `extra`
    rows: one orthonormal basis of rank + extra_rank rows about x's mean.

    A material model decodes u / d and the sensitivities S_i / d with one basis. Fitted on all the rows together,
    the S_i take modes from u and u's own error grows (docs/materials.md); here u keeps its own modes and S_i get
    theirs on top."""
    if not 1 <= rank < len(x):
        raise ValueError(f"--rank: must be between 1 and {len(x) - 1} (the number of snapshots - 1), got {rank}")
    if not 1 <= extra_rank < len(extra):
        raise ValueError(f"--sensitivity-rank: must be between 1 and {len(extra) - 1}, got {extra_rank}")
    primary = fit_pca(x, rank)
    rest = np.asarray(extra, dtype=np.float64) - primary.mean
    rest -= (rest @ primary.basis.T) @ primary.basis
    more, _ = _modes(rest, extra_rank)
    return Pca(mean=primary.mean, basis=_orthonormal(np.vstack([primary.basis, more])),
               singular_values=primary.singular_values, n_primary=primary.rank)


def fit_pca(x: np.ndarray, rank: int) -> Pca:
    """Fit the leading `rank` modes of rows x (n_snapshots, 3 n_nodes)."""
    if not 1 <= rank < len(x):
        raise ValueError(f"--rank: must be between 1 and {len(x) - 1} (the number of snapshots - 1), got {rank}")
    x = np.asarray(x, dtype=np.float64)
    mean = x.mean(axis=0)
    basis, s = _modes(x - mean, rank)
    return Pca(mean=mean, basis=basis, singular_values=s)
