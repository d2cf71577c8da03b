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

    @property
    def rank(self) -> int:
        return len(self.basis)

    @property
    def energy(self) -> float:
        """Fraction of the centred data's variance that the kept modes capture."""
        s2 = self.singular_values**2
        return float(s2[: self.rank].sum() / s2.sum())

    def encode(self, x: np.ndarray) -> np.ndarray:
        return (x - self.mean) @ self.basis.T  # (n, rank)

    def decode(self, coefficients: np.ndarray) -> np.ndarray:
        return self.mean + coefficients @ self.basis  # (n, 3 n_nodes)


def fit_pca(x: np.ndarray, rank: int) -> Pca:
    """Fit the leading `rank` modes of rows x (n_snapshots, 3 n_nodes)."""
    if not 1 <= rank < len(x):
        raise ValueError(f"--rank: must be between 1 and {len(x) - 1} (the number of snapshots - 1), got {rank}")
    x = np.asarray(x, dtype=np.float64)
    mean = x.mean(axis=0)
    xc = x - mean
    gram = xc @ xc.T  # (n, n)
    eigval, eigvec = np.linalg.eigh(gram)
    order = np.argsort(eigval)[::-1]
    eigval, eigvec = np.clip(eigval[order], 0.0, None), eigvec[:, order]
    s = np.sqrt(eigval)
    numerical = int((s > 1e-9 * s[0]).sum())  # a linear sweep's f = u / d spans 2 modes, whatever rank is asked
    if rank > numerical:
        log.warning("rank %d asked for, the snapshots span %d modes: using %d", rank, numerical, numerical)
        rank = numerical
    basis = (eigvec[:, :rank] / s[:rank]).T @ xc  # (rank, 3 n_nodes)
    # One Gram-Schmidt pass removes the round-off the S^-1 scaling leaves in weak modes.
    q, r = np.linalg.qr(basis.T)
    basis = (q * np.sign(np.diag(r))).T
    return Pca(mean=mean, basis=basis, singular_values=s)
