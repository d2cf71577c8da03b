import numpy as np

from training.network import train


def _smooth_targets(n=200, seed=0):
    rng = np.random.default_rng(seed)
    x = np.stack([rng.uniform(0, 10, n), rng.uniform(-10, 10, n)], axis=1)
    d, a = x[:, 0], np.radians(x[:, 1])
    y = np.stack([d * np.cos(a), d * np.sin(a), 0.05 * d**2, d * a**2], axis=1)
    return x, y


def test_training_is_deterministic_given_the_seed():
    x, y = _smooth_targets()
    a, _, _ = train(x, y, width=16, max_iterations=60, seed=3)
    b, _, _ = train(x, y, width=16, max_iterations=60, seed=3)
    for pa, pb in zip(a.parameters(), b.parameters()):
        assert (pa == pb).all()


def test_smooth_map_is_fitted_to_a_small_error():
    """Variable projection fits this 2-D smooth map to < 1e-3 of its range with 30 tanh units."""
    import torch

    x, y = _smooth_targets()
    net, s, info = train(x, y, width=30, max_iterations=500)
    xt, yt = _smooth_targets(50, seed=1)
    with torch.no_grad():
        pred = net(torch.from_numpy((xt - s.input_center) / s.input_scale)).numpy() * s.coef_scale + s.coef_mean
    assert np.abs(pred - yt).max() < 1e-3 * np.abs(yt).max()
    assert info["iterations"] <= 500 and info["final_loss"] < 1e-6
