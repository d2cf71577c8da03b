import numpy as np
import pytest

from training.metrics import ANGLE_FLOOR_MM, case_errors


def test_metrics_of_a_known_error():
    """Reference: node 0 moves (3, 0, 0), node 1 (0, 4, 0); prediction rotates node 1 by 90 deg and
    shifts node 0 by 0.3 mm in y: e_NN = |(0,-4,4)| = 4 sqrt 2, alpha = 90, e_r = 4 / 4 = 100 %."""
    ref = np.array([[3.0, 0, 0], [0, 4.0, 0]])
    pred = np.array([[3.0, 0.3, 0], [0, 0, 4.0]])
    e = case_errors(pred, ref)
    assert e["e_nn_mm"] == pytest.approx(4 * np.sqrt(2))
    assert e["alpha_deg"] == pytest.approx(90.0)
    assert e["e_r_percent"] == pytest.approx(100.0)
    assert e["mean_mm"] == pytest.approx((0.3 + 4 * np.sqrt(2)) / 2)


def test_nodes_below_the_floor_do_not_set_the_angle():
    ref = np.array([[5.0, 0, 0], [ANGLE_FLOOR_MM / 2, 0, 0]])
    pred = np.array([[5.0, 0, 0], [-ANGLE_FLOOR_MM / 2, 0, 0]])  # the slow node points backwards
    assert case_errors(pred, ref)["alpha_deg"] == pytest.approx(0.0, abs=1e-6)


def test_exact_prediction_has_zero_error():
    ref = np.random.default_rng(0).normal(size=(50, 3))
    e = case_errors(ref.copy(), ref)
    assert e["e_nn_mm"] == 0 and e["e_r_percent"] == 0 and e["alpha_deg"] == pytest.approx(0, abs=1e-5)
