"""/docs and /redoc work offline: every script and stylesheet is served by the service itself."""

import re

import pytest


@pytest.mark.parametrize("page", ["/docs", "/redoc"])
def test_docs_page_references_no_outside_url_and_its_assets_are_served(client, page):
    html = client.get(page)
    assert html.status_code == 200
    assert not re.findall(r"https?://", html.text), re.findall(r"https?://\S+", html.text)
    assets = re.findall(r"""(?:src|href)=["']([^"']+)["']""", html.text)
    assert any(a.endswith(".js") for a in assets)
    for asset in assets:
        assert client.get(asset).status_code == 200, asset
