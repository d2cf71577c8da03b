"""The container's HEALTHCHECK follows the service's own settings: its port, and HTTPS when a certificate is set."""

import os
import subprocess
import sys

from tools.loadtest import free_port

from .test_main import _serve


def _check(env: dict) -> int:
    return subprocess.run([sys.executable, "-m", "service.healthcheck"], capture_output=True, timeout=30,
                          env={**os.environ, **env}).returncode


def test_healthcheck_follows_port_and_tls(certificate):
    cert, key = certificate
    import ssl

    with _serve("--ssl-certfile", str(cert), "--ssl-keyfile", str(key), scheme="https",
                context=ssl.create_default_context(cafile=str(cert))) as (url, _):
        port = url.rsplit(":", 1)[1]
        assert _check({"DEFORM_PORT": port, "DEFORM_SSL_CERTFILE": str(cert), "DEFORM_SSL_KEYFILE": str(key)}) == 0
        assert _check({"DEFORM_PORT": port}) == 1  # plain HTTP to a TLS port is not healthy
    assert _check({"DEFORM_PORT": str(free_port())}) == 1  # nothing listening
