"""Small helpers the service tests share."""

from contextlib import contextmanager

import numpy as np
from fastapi.testclient import TestClient


@contextmanager
def served(model, **settings):
    """A TestClient of the app serving `model` (lifespan run), with other settings as given."""
    from service.app import create_app
    from service.settings import Settings

    with TestClient(create_app(Settings(model=model, **settings))) as client:
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
