import numpy as np
import pytest

from training.pca import fit_pca, fit_pca_with_extra


def _low_rank(n=60, m=900, rank=5, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, rank)) @ rng.normal(size=(rank, m)) + rng.normal(size=m)


def test_exact_rank_data_is_reconstructed_to_round_off():
    x = _low_rank(rank=5)
    pca = fit_pca(x, 5)
    np.testing.assert_allclose(pca.decode(pca.encode(x)), x, atol=1e-10)
    assert pca.energy == pytest.approx(1.0, abs=1e-12)


def test_basis_is_orthonormal_and_matches_thin_svd():
    x = _low_rank(rank=12) + 1e-3 * np.random.default_rng(1).normal(size=(60, 900))
    pca = fit_pca(x, 8)
    np.testing.assert_allclose(pca.basis @ pca.basis.T, np.eye(8), atol=1e-12)
    s = np.linalg.svd(x - x.mean(0), compute_uv=False)
    np.testing.assert_allclose(pca.singular_values[:20], s[:20], rtol=1e-9, atol=1e-9 * s[0])
    _, _, vt = np.linalg.svd(x - x.mean(0), full_matrices=False)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", pca.basis, vt[:8])), 1.0, atol=1e-8)


def test_truncation_error_is_the_discarded_energy():
    """Eckart-Young: the squared residual of the rank-r fit equals the sum of the discarded s^2."""
    x = _low_rank(rank=20)
    pca = fit_pca(x, 6)
    residual = ((x - pca.decode(pca.encode(x))) ** 2).sum()
    assert residual == pytest.approx((pca.singular_values[6:] ** 2).sum(), rel=1e-8)


def test_rank_out_of_range_names_the_flag():
    with pytest.raises(ValueError, match="--rank"):
        fit_pca(_low_rank(n=10), 10)


def test_extra_modes_leave_the_primary_rows_their_own_basis_and_span_the_extra_rows():
    """The primary rows keep exactly the modes fit_pca gives them (same subspace, same energy); the extra rows,
    drawn from 3 directions the primary rows do not span (about the primary mean), are reconstructed to round-off
    by 3 extra modes, and the whole basis is orthonormal."""
    rng = np.random.default_rng(2)
    x = _low_rank(rank=20)
    extra = x.mean(0) + rng.normal(size=(40, 3)) @ rng.normal(size=(3, 900))
    plain, both = fit_pca(x, 6), fit_pca_with_extra(x, extra, 6, 3)
    assert (both.rank, both.n_primary) == (9, 6)
    np.testing.assert_allclose(both.basis @ both.basis.T, np.eye(9), atol=1e-12)
    np.testing.assert_allclose(both.basis[:6] @ plain.basis.T @ plain.basis, both.basis[:6], atol=1e-10)
    assert both.energy == pytest.approx(plain.energy, rel=1e-12)
    np.testing.assert_allclose(both.decode(both.encode(extra)), extra, atol=1e-9)
    # the primary rows lose nothing to the extra modes: never worse than their own rank-6 fit
    assert ((x - both.decode(both.encode(x))) ** 2).sum() <= ((x - plain.decode(plain.encode(x))) ** 2).sum() + 1e-9


def test_extra_rank_out_of_range_names_the_flag():
    x = _low_rank(n=10)
    with pytest.raises(ValueError, match="--sensitivity-rank"):
        fit_pca_with_extra(x, x[:4], 3, 4)
