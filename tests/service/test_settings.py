"""Bad settings stop `python -m service` at start with a one-line message naming the field."""

import os
import shutil
import subprocess
import sys

from .conftest import DEFAULT


def _serve(*args, env=None):
    return subprocess.run([sys.executable, "-m", "service", *args], capture_output=True, text=True, timeout=60,
                          env={**os.environ, **(env or {})})


def test_bad_settings_fail_fast_naming_the_field(tmp_path):
    run = _serve("--port", "70000")
    assert run.returncode == 2 and "--port" in run.stderr and "65535" in run.stderr
    run = _serve("--model", str(tmp_path))
    assert run.returncode == 2 and "--model" in run.stderr and "not a model folder" in run.stderr
    run = _serve(env={"DEFORM_THREADS": "0"})
    assert run.returncode == 2 and "--threads" in run.stderr
    assert "Traceback" not in run.stderr


def test_corrupt_model_stops_the_start(tmp_path):
    bad = tmp_path / "m"
    shutil.copytree(DEFAULT, bad)
    (bad / "mesh.npz").write_bytes(b"not a mesh")
    run = _serve("--model", str(bad))
    assert run.returncode == 2 and "mesh.npz does not match its sha256" in run.stderr


def test_deployment_settings_fail_fast(tmp_path):
    cert = tmp_path / "cert.pem"
    cert.write_text("x")
    run = _serve("--ssl-certfile", str(cert))
    assert run.returncode == 2 and "ssl_certfile and ssl_keyfile together" in run.stderr
    empty = tmp_path / "tokens"
    empty.write_text("# no tokens yet\n\n")
    run = _serve("--auth-token-file", str(empty))
    assert run.returncode == 2 and "holds no token" in run.stderr
    run = _serve(env={"DEFORM_CORS_ORIGINS": "*"})
    assert run.returncode == 2 and "--cors-origins" in run.stderr and "no wildcard" in run.stderr
    run = _serve("--access-log", "xml")
    assert run.returncode == 2 and "--access-log" in run.stderr and "Traceback" not in run.stderr


def test_lists_come_comma_separated_from_flags_and_env(monkeypatch):
    from service.settings import Settings

    monkeypatch.setenv("DEFORM_CORS_ORIGINS", "https://a.example.org, http://127.0.0.1:5173")
    monkeypatch.setenv("DEFORM_AUTH_TOKENS", "t1,t2")
    s = Settings()
    assert s.cors_origins == ["https://a.example.org", "http://127.0.0.1:5173"] and s.tokens() == {"t1", "t2"}
    assert Settings(auth_tokens="t3").tokens() == {"t3"}
    assert "t1" not in repr(s)  # tokens stay out of logs and tracebacks


def test_locked_down_parts_are_off_by_default():
    from service.settings import Settings

    s = Settings()
    assert (s.tokens(), s.rate_limit, s.cors_origins, s.ssl_certfile) == (frozenset(), 0.0, [], None)
