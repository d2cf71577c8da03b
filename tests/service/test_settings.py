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
