import shutil
import subprocess
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from .helpers import served

DEFAULT = Path(__file__).resolve().parents[2] / "models" / "default"


@pytest.fixture(scope="session")
def settings():
    from service.settings import Settings

    return Settings(model=DEFAULT, max_points=50, max_body_bytes=64 * 1024)


@pytest.fixture(scope="session")
def client(settings):
    from service.app import create_app

    with TestClient(create_app(settings)) as c:
        yield c


# The tiny model (tests/conftest.py) for the viewer, export and OpenIGTLink tests.
@pytest.fixture(scope="session")
def tiny_folder(tiny_model):
    from service.model import read_model_folder

    return read_model_folder(tiny_model)


@pytest.fixture(scope="session")
def tiny_predictor(tiny_folder):
    from service.model import Predictor

    return Predictor(tiny_folder)


@pytest.fixture(scope="session")
def tiny_client(tiny_model):
    with served(tiny_model) as client:
        yield client


@pytest.fixture(scope="session")
def predictor(settings):
    from service.model import Predictor, read_model_folder

    return Predictor(read_model_folder(settings.model))


@pytest.fixture(scope="session")
def request_model(settings, predictor):
    """The PredictRequest model the app builds from the default model's manifest."""
    from service.info import model_info
    from service.predict.schemas import predict_request_model

    return predict_request_model(model_info(predictor.folder, settings), settings.max_points)


@pytest.fixture(scope="session")
def certificate(tmp_path_factory):
    """A self-signed certificate for 127.0.0.1, made here with the openssl command."""
    if shutil.which("openssl") is None:
        pytest.skip("no openssl command to make a test certificate")
    folder = tmp_path_factory.mktemp("tls")
    cert, key = folder / "cert.pem", folder / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=127.0.0.1",
                    "-addext", "subjectAltName=IP:127.0.0.1", "-keyout", str(key), "-out", str(cert)],
                   check=True, capture_output=True)
    return cert, key
