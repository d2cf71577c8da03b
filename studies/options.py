"""What the study commands share: scene paths, the flags they all parse, scene variants and JSON-ready numbers."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from contracts.cli import number

SCENES = Path("fem_offline/scenes")
# The studies' base: uniform 12/4/2 mm sizes, the pointwise element, the tip in contact (the physics
# the committed grid-convergence and element results were measured with).
GRID_STUDY_SCENE = SCENES / "grid_study_base.toml"
# The served model's scene (Taylor-Hood, graded mesh): for the studies that describe models/default.
SERVED_SCENE = SCENES / "default.toml"
# The Taylor-Hood contact grid-convergence study's folder (`make fe-error-taylor-hood`) and its levels.
TAYLOR_HOOD_STUDY = Path("runs/convergence_contact_taylor_hood")
TAYLOR_HOOD_SCALES = [1.3, 1.0, 0.769, 0.5917]


def _pair(text: str, flag: str, form: str) -> tuple[float, float]:
    """Two numbers A:B, or an argparse error naming the flag and the form."""
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{flag}: {text!r} is not {form}") from None
    return a, b


def case_arg(text: str) -> tuple[float, float]:
    """argparse type of one case, D_MM:BETA_DEG (e.g. 10:0)."""
    return _pair(text, "--cases", "D_MM:BETA_DEG (e.g. 10:0)")


def case_text(case: tuple[float, float]) -> str:
    """The flag form of a case, as case_arg reads it back."""
    return f"{case[0]:g}:{case[1]:g}"


def add_scene_flag(ap: argparse.ArgumentParser, default: Path = GRID_STUDY_SCENE, what: str = "the scene") -> None:
    ap.add_argument("--scene", type=Path, default=default, help=f"{what} (default {default})")


def add_cases_flag(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--cases", type=case_arg, nargs="+", metavar="D_MM:BETA_DEG",
                    help="the cases (default: the hard cases, studies.convergence.HARD_CASES)")


def add_scales_flag(ap: argparse.ArgumentParser, default: list[float], what: str) -> None:
    ap.add_argument("--scales", type=number("--scales", minimum=1e-3), nargs="+", default=default, help=what)


def add_study_flags(ap: argparse.ArgumentParser, *, scales: list[float] = TAYLOR_HOOD_SCALES) -> None:
    """--study (a convergence study's folder of meshes and checkpoints) and --scales (its levels)."""
    ap.add_argument("--study", type=Path, default=TAYLOR_HOOD_STUDY,
                    help=f"a grid-convergence study's folder, meshes and path checkpoints "
                         f"(default {TAYLOR_HOOD_STUDY})")
    add_scales_flag(ap, scales,
                    "its levels, coarsest first; per case the three finest that solved it give the estimate")


def parser(prog: str, doc: str) -> argparse.ArgumentParser:
    """A study command's parser: `python -m studies NAME`, the module docstring as its description."""
    return argparse.ArgumentParser(prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)


def with_tolerances(scene, rtol: float, contact_tol_mm: float):
    """The scene with solver.rtol and guide.contact_tol_mm replaced (validated as a scene file would be)."""
    data = scene.model_dump()
    data["solver"]["rtol"] = rtol
    data["guide"]["contact_tol_mm"] = contact_tol_mm
    return type(scene).model_validate(data)


def tolerance_arg(text: str) -> tuple[float, float]:
    """argparse type of RTOL:CONTACT_TOL_MM (e.g. 1e-6:0.005)."""
    return _pair(text, "a tolerance", "RTOL:CONTACT_TOL_MM (e.g. 1e-6:0.005)")


def json_ready(x, digits: int | None = None):
    """Arrays to lists, numpy scalars to Python, NaN/inf to null (strict JSON);
    floats to `digits` significant digits if given."""
    if isinstance(x, dict):
        return {k: json_ready(v, digits) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [json_ready(v, digits) for v in (x.tolist() if isinstance(x, np.ndarray) else x)]
    if isinstance(x, (float, np.floating)):
        if not np.isfinite(x):
            return None
        return float(f"{x:.{digits}g}") if digits else float(x)
    if isinstance(x, np.integer):
        return int(x)
    return x
