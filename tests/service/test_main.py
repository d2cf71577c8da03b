"""`python -m service` as deployed: TLS from uvicorn's certificate settings, the access log, worker processes."""

import json
import os
import re
import ssl
import subprocess
import sys
import time
import urllib.error
import urllib.request
from contextlib import contextmanager

import pytest

from tools.loadtest import free_port

from .conftest import DEFAULT


@contextmanager
def _serve(*flags, scheme="http", context=None):
    """Start the service with `flags` on a free port; yield (url, process) once /readyz answers."""
    port = free_port()
    url = f"{scheme}://127.0.0.1:{port}"
    proc = subprocess.Popen([sys.executable, "-m", "service", "--model", str(DEFAULT), "--port", str(port), *flags],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                urllib.request.urlopen(f"{url}/readyz", timeout=2, context=context)
                break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    stderr = proc.communicate(timeout=10)[1]
                    raise AssertionError(f"the service did not start: {stderr[-2000:]}") from None
                time.sleep(0.25)
        yield url, proc
    finally:
        proc.terminate()
        proc.wait(20)


def test_tls_serves_https_with_the_certificate_and_logs_json_lines(certificate):
    cert, key = certificate
    trusted = ssl.create_default_context(cafile=str(cert))
    with _serve("--ssl-certfile", str(cert), "--ssl-keyfile", str(key), "--access-log", "json",
                scheme="https", context=trusted) as (url, proc):
        body = json.dumps({"displacement_mm": 5.0, "angle_deg": 2.0, "region": "markers"}).encode()
        reply = urllib.request.urlopen(urllib.request.Request(
            f"{url}/predict", data=body, headers={"content-type": "application/json"}), context=trusted, timeout=10)
        assert reply.status == 200 and json.loads(reply.read())["count"] == 8
        with pytest.raises(urllib.error.URLError) as untrusted:  # served with that certificate, not another
            urllib.request.urlopen(f"{url}/healthz", context=ssl.create_default_context(), timeout=10)
        assert isinstance(untrusted.value.reason, ssl.SSLCertVerificationError)
        with pytest.raises(OSError):  # no plain HTTP on the TLS port
            urllib.request.urlopen(url.replace("https", "http") + "/healthz", timeout=10)
        proc.terminate()
        out, _ = proc.communicate(timeout=20)
    lines = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    assert {"method": "POST", "path": "/predict", "status": 200}.items() <= lines[-1].items()
    assert any(line["path"] == "/readyz" for line in lines)


def test_the_access_log_can_be_switched_off():
    with _serve("--access-log", "off", "--log-level", "info") as (url, proc):
        for _ in range(3):
            urllib.request.urlopen(f"{url}/healthz", timeout=10).read()
        proc.terminate()
        out, err = proc.communicate(timeout=20)
    assert "GET /healthz" not in out + err and "Uvicorn running" in out + err  # logging works; no request lines


def test_workers_read_the_flags_and_metrics_add_up_over_them():
    body = json.dumps({"displacement_mm": 5.0, "angle_deg": 2.0, "region": "markers"}).encode()
    with _serve("--workers", "2", "--max-points", "7", "--access-log", "off") as (url, _):
        limits = [json.loads(urllib.request.urlopen(f"{url}/model", timeout=10).read())["limits"] for _ in range(4)]
        for _ in range(12):  # a new connection each: they land on either worker
            urllib.request.urlopen(urllib.request.Request(
                f"{url}/predict", data=body, headers={"content-type": "application/json"}), timeout=10).read()
        texts = [urllib.request.urlopen(f"{url}/metrics", timeout=10).read().decode() for _ in range(6)]
    assert all(limit["max_points"] == 7 for limit in limits)
    counts = {float(re.search(r'predict_requests_total{format="json",region="markers",status="200"} (\S+)', t).group(1))
              for t in texts}
    assert counts == {12.0}  # every scrape, whichever worker answers it, counts both workers' requests
