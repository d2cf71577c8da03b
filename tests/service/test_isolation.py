"""The service never imports torch, gmsh, scikit-fem or the FE and training code."""

import subprocess
import sys


def test_service_imports_no_training_or_fe_code():
    code = ("import sys, service.app, service.__main__; from service.app import create_app; create_app(); "
            "bad = [m for m in ('torch', 'gmsh', 'skfem', 'fem_offline', 'training', 'meshio') if m in sys.modules]; "
            "print(bad); sys.exit(1 if bad else 0)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
