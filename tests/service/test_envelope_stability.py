"""Inputs at the envelope's corners and edges, through onnxruntime and through the service (stability suite)."""

import numpy as np
import pytest

from service.model import Predictor, read_model_folder

from .conftest import DEFAULT

CORNERS_AND_EDGES = [(d, a) for d in (0.0, 5.0, 10.0) for a in (-10.0, 0.0, 10.0)]


@pytest.fixture(scope="module")
def predictor():
    return Predictor(read_model_folder(DEFAULT))


@pytest.mark.parametrize(("d", "a"), CORNERS_AND_EDGES)
def test_envelope_edges_are_physical_through_onnxruntime(predictor, d, a):
    """The guide is the fastest-moving point: no node moves more than 2 % beyond the guide's d
    (a field blowing up at the envelope's edge would), and d = 0 leaves the mesh in place."""
    u = predictor.displacement(d, a)
    peak = np.linalg.norm(u, axis=1).max()
    assert np.isfinite(u).all()
    assert peak <= 1.02 * d + 0.005, peak
    if d > 0:
        assert peak >= 0.98 * d  # the guide patch does follow the guide


@pytest.mark.parametrize(("d", "a"), CORNERS_AND_EDGES)
def test_envelope_edges_through_the_service_match_onnxruntime(client, predictor, d, a):
    r = client.post("/predict", json={"displacement_mm": d, "angle_deg": a},
                    headers={"accept": "application/octet-stream"})
    assert r.status_code == 200
    got = np.frombuffer(r.content, dtype="<f4").reshape(-1, 3)
    np.testing.assert_allclose(got, predictor.folder.nodes + predictor.displacement(d, a), atol=1e-4)


@pytest.mark.parametrize(("d", "a"), [(10.0 + 1e-6, 0.0), (-1e-6, 0.0), (5.0, 10.0 + 1e-6), (5.0, -10.0 - 1e-6)])
def test_just_outside_the_envelope_is_refused(client, d, a):
    r = client.post("/predict", json={"displacement_mm": d, "angle_deg": a})
    assert r.status_code == 422 and "training envelope" in r.text


def test_the_served_envelope_stops_where_the_sweep_inverts(tiny_client, tiny_folder):
    """The tiny model's linear sweep turns elements inside out beyond its cut (tests/conftest.py): the cut
    itself is answered; a step past it, and the sweep's own largest push, get 422."""
    cut = tiny_folder.manifest.envelope_cut
    d = cut.valid_up_to_mm
    info = tiny_client.get("/model").json()
    assert info["envelope"]["displacement_mm"] == [0.0, d] and info["envelope_cut"]["valid_up_to_mm"] == d
    assert info["envelope_cut"]["n_inverted"] > 0
    assert tiny_client.post("/predict", json={"displacement_mm": d, "angle_deg": 10.0}).status_code == 200
    for beyond in (d + 1e-6, cut.sweep_envelope.displacement_mm[1]):
        r = tiny_client.post("/predict", json={"displacement_mm": beyond, "angle_deg": 0.0})
        assert r.status_code == 422 and "training envelope" in r.text, (beyond, r.text)
