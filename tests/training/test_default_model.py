"""The committed models/default: loads, hashes match, stored metrics meet the targets."""

from pathlib import Path

import numpy as np

from service.model import Predictor, load_model_folder

DEFAULT = Path(__file__).resolve().parents[2] / "models" / "default"


def test_default_model_loads_and_meets_the_paper_and_our_targets():
    folder = load_model_folder(DEFAULT)  # checks every sha256
    m = folder.manifest
    t3, off = m["metrics"]["table3_summary"], m["metrics"]["offgrid_summary"]
    assert [(r["displacement_mm"], r["angle_deg"]) for r in m["metrics"]["table3"]] == [
        (7.75, -5.0), (4.25, -3.0), (5.25, -2.0), (1.5, -1.0), (2.5, 2.0)]
    assert t3["e_nn_mm"] <= 0.03  # the paper's Table 3
    assert t3["e_nn_mm"] <= 0.01 and t3["e_r_percent"] <= 0.3  # our targets
    assert off["n_cases"] >= 20 and off["e_nn_mm"] <= 0.01
    assert m["metrics"]["onnx_vs_float64_max_abs_mm"] < 1e-4
    assert sum(p.stat().st_size for p in DEFAULT.iterdir()) <= 30e6


def test_default_model_subset_equals_full_decode():
    folder = load_model_folder(DEFAULT)
    p = Predictor(folder)
    full = p.displacement(7.75, -5.0)
    for region in ("markers", "prostate_surface"):
        ids = folder.regions[region]
        np.testing.assert_allclose(p.displacement(7.75, -5.0, ids), full[ids], atol=1e-5)
