from pathlib import Path

import pytest
from fastapi.testclient import TestClient

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
