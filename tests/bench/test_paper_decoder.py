"""The paper-scale decoder carries the surrogate's PCA to another mesh by a linear map, exactly."""

import numpy as np
import scipy.sparse as sp

from bench.paper_decoder import on_fine_mesh
from training.pca import Pca


def test_the_fine_decode_is_the_interpolated_coarse_decode():
    rng = np.random.default_rng(0)
    n_coarse, n_fine, rank = 7, 11, 3
    pca = Pca(mean=rng.normal(size=3 * n_coarse), basis=rng.normal(size=(rank, 3 * n_coarse)),
              singular_values=np.ones(rank))
    W = sp.random(n_fine, n_coarse, density=0.5, random_state=1, format="csr")
    fine = on_fine_mesh(pca, W)
    c = rng.normal(size=(2, rank))
    coarse_u = pca.decode(c).reshape(2, n_coarse, 3)
    np.testing.assert_allclose(fine.decode(c).reshape(2, n_fine, 3), np.stack([W @ u for u in coarse_u]), atol=1e-12)
