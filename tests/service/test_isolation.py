"""The service never imports torch, gmsh, scikit-fem or the FE code; bad settings stop it at start."""

import subprocess
import sys

from conftest import DEFAULT


def test_service_imports_no_training_or_fe_code():
    code = ("import sys, service.app, service.__main__; from service.app import create_app; create_app(); "
            "bad = [m for m in ('torch', 'gmsh', 'skfem', 'fem_offline', 'training', 'meshio') if m in sys.modules]; "
            "print(bad); sys.exit(1 if bad else 0)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


def _serve(*args, env=None):
    import os

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
    import shutil

    bad = tmp_path / "m"
    shutil.copytree(DEFAULT, bad)
    (bad / "mesh.npz").write_bytes(b"not a mesh")
    run = _serve("--model", str(bad))
    assert run.returncode == 2 and "mesh.npz does not match its sha256" in run.stderr
