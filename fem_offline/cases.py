"""Off-grid cases: random (displacement, angle) pairs inside the sweep's envelope, each solved from rest.

They are the held-out set training reports on. Drawn from a fixed seed, so the same command gives
the same cases; a finished case file is never recomputed, so an interrupted run resumes.
"""

from __future__ import annotations

import logging
from pathlib import Path

from contracts import sweep as folder
from contracts.envelope import Envelope
from contracts.mesh import TetMesh

from .linear import measured
from .newton import ConvergenceError
from .scene import Scene
from .solve import solve_case

log = logging.getLogger(__name__)


def draw_cases(scene: Scene, n: int, seed: int) -> list[tuple[float, float]]:
    """n (displacement_mm, angle_deg) pairs, uniform inside the envelope, from the first load step up."""
    sweep = scene.sweep
    envelope = Envelope.of_grid(sweep.displacements_mm, sweep.angles_deg)
    return envelope.sample(n, seed, min_displacement_mm=sweep.displacement_step_mm)


def case_file(out: Path, index: int) -> Path:
    return out / f"offgrid_{index:03d}.npz"


def solve_one(scene_json: str, mesh_path: str, out: str, index: int, d_mm: float, angle_deg: float) -> str | None:
    """Solve one case and write it; the error message if it did not converge."""
    from .sweep import _problem

    problem = _problem(scene_json, mesh_path)
    try:
        u, stats = solve_case(problem, d_mm, angle_deg)
    except ConvergenceError as exc:
        return f"case {index} ({d_mm} mm, {angle_deg} deg): {exc}"
    stats = measured(problem, u, stats)
    if not stats.min_det_f > 0:
        log.warning("case %d (%g mm, %g deg): det(I + grad u) %.3g <= 0, an element is inside out", index, d_mm,
                    angle_deg, stats.min_det_f)
    folder.write_case(case_file(Path(out), index), u, displacement_mm=d_mm, angle_deg=angle_deg,
                      record=folder.CaseRecord(**stats.record()), reference_positions=problem.mesh.nodes,
                      scene_sha256=problem.scene.sha256())
    log.info("case %d: %g mm, %g deg, %d Newton iterations, %.1f s", index, d_mm, angle_deg, stats.iterations, stats.seconds)
    return None


def solve_cases(scene: Scene, mesh_path: Path, out: Path, n: int, seed: int, *, workers: int = 2) -> list[str]:
    """Solve the missing cases of the draw on a process pool; returns the failures."""
    from tqdm import tqdm

    from .sweep import single_threaded_pool

    out.mkdir(parents=True, exist_ok=True)
    todo = [(i, d, a) for i, (d, a) in enumerate(draw_cases(scene, n, seed)) if not case_file(out, i).exists()]
    failures = []
    with single_threaded_pool(workers) as pool, tqdm(total=n, initial=n - len(todo), unit="case") as bar:
        futures = [pool.submit(solve_one, scene.model_dump_json(), str(mesh_path), str(out), *job) for job in todo]
        for f in futures:
            error = f.result()
            if error:
                failures.append(error)
            bar.update(1)
    return failures


def mesh_for_cases(mesh: TetMesh, out: Path) -> Path:
    """The cases' own mesh file, written once into `out`; every case is on its nodes."""
    import numpy as np

    from contracts.mesh import read_mesh, write_mesh

    path = out / folder.MESH_FILE
    if not path.exists():
        write_mesh(path, mesh)
    elif not np.array_equal(read_mesh(path).nodes, mesh.nodes):
        raise ValueError(f"--out: {out} holds cases on another mesh; use a new folder or the same --mesh")
    return path
