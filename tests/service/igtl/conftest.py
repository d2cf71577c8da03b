"""A served tiny model with OpenIGTLink on, as `--igtl true` starts it, and a pyigtl client as a real peer."""

import pyigtl
import pytest
from fastapi.testclient import TestClient

from tools.loadtest import free_port

from ..helpers import prostate_point


@pytest.fixture(scope="module")
def served(tiny_model, tiny_folder):  # noqa: F811
    """(HTTP client, OpenIGTLink port, the --igtl-targets lesion): one target in the prostate."""
    from service.app import create_app
    from service.settings import Settings

    target = prostate_point(tiny_folder)
    settings = Settings(model=tiny_model, igtl=True, igtl_port=free_port(), igtl_targets={"lesion": target})
    with TestClient(create_app(settings)) as client:
        yield client, settings.igtl_port, target


@pytest.fixture()
def peer(served):
    client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=served[1])
    yield client
    client.stop()
