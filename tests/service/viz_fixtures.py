"""The tiny model (built in seconds by tests/training/conftest.py) for the viewer, export and OpenIGTLink tests.

These tests use it instead of models/default so that they do not depend on the default model's
format. Import the fixtures by name into a test module: `from viz_fixtures import tiny_client, ...`.
"""

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.training.conftest import tiny_model, tiny_sweep  # noqa: F401  (session fixtures, reused)


@pytest.fixture(scope="session")
def tiny_folder(tiny_model):  # noqa: F811
    from service.model import read_model_folder

    return read_model_folder(tiny_model)


@pytest.fixture(scope="session")
def tiny_predictor(tiny_folder):
    from service.model import Predictor

    return Predictor(tiny_folder)


@pytest.fixture(scope="session")
def tiny_client(tiny_model):  # noqa: F811
    from service.app import create_app
    from service.settings import Settings

    with TestClient(create_app(Settings(model=tiny_model))) as client:
        yield client


def predict_json(client, **body) -> dict:
    """POST /predict as JSON; assert 200."""
    reply = client.post("/predict", json=body)
    assert reply.status_code == 200, reply.text
    return reply.json()


def prostate_point(folder) -> list[float]:
    """A reference point inside the prostate: the centroid of its first tet."""
    tissue = folder.manifest.mesh.tissues.index("prostate")
    tet = folder.tets[np.flatnonzero(folder.mesh.tissue == tissue)[0]]
    return folder.nodes[tet[:4]].mean(axis=0).tolist()
