"""Run `python -m fem_offline` and write variants of tiny.toml for the CLI and sweep tests."""

import subprocess
import sys
from pathlib import Path

from .conftest import SCENES

ROOT = Path(__file__).resolve().parents[2]

LINEAR = "[effects]\ngeometric_nonlinearity = false\n"
MINI = """[sweep]
displacement_step_mm = 1.0
displacement_max_mm = 2.0
angle_min_deg = -10.0
angle_max_deg = 10.0
angle_step_deg = 20.0
"""
# Every soft tissue's stiffness as an input (tiny.toml has none): the sweep stores du/d ln E per tissue
MATERIALS = "".join(f"""[materials.{name}]
youngs_kpa_range = [{lo}, {hi}]
std_percent = 20.0
""" for name, lo, hi in (("prostate", 50.0, 85.0), ("rectal_wall", 140.0, 215.0), ("adipose", 8.5, 13.5),
                         ("bladder", 80.0, 125.0)))


def cli(*args, **kw):
    return subprocess.run([sys.executable, "-m", "fem_offline", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, **kw)


def scene_file(tmp_path, name, extra):
    """tiny.toml with `extra`'s keys on top (it `extends` tiny.toml)."""
    path = tmp_path / f"{name}.toml"
    path.write_text(f'extends = "{SCENES / "tiny.toml"}"\n' + extra)
    return path
