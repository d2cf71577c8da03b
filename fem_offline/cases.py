"""Off-grid cases: random (displacement, angle) pairs inside the sweep's envelope, each solved to equilibrium.

They are the held-out set training reports on. Drawn from a fixed seed, so the same command gives
the same cases; a finished case file is never recomputed, so an interrupted run resumes.

A case is load-stepped from rest, or, given the sweep of the same scene and mesh (`sweep=`), Newton
starts at the guide position (d, beta) itself from the field interpolated between the four grid
snapshots around it. The physics is conservative (hyperelastic tissue, a fixed table and bones,
frictionless contact), so an equilibrium does not depend on the path that reached it: the start
changes the work, not the answer, which must still meet solver.rtol and guide.contact_tol_mm. A
start that does not converge in one step falls back to the path from rest. Each file records which
start it had (`started_from`). Measured on the default model's 16,296-tet mesh: the 8 cases took
17.7 min from rest and 49 s from the sweep, and the two starts' equilibria differ by up to 0.015 mm
at single nodes, what the contact tolerance leaves open (README, "Off-grid cases started from the sweep").
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from contracts import sweep as folder
from contracts.envelope import Envelope
from contracts.mesh import TetMesh

from fem_offline.fe.continuation import PathState, solve_path
from fem_offline.fe.linear import measured
from fem_offline.fe.newton import ConvergenceError
from fem_offline.fe.problem import Problem
from fem_offline.scene import Scene
from fem_offline.fe.solve import solve_case

log = logging.getLogger(__name__)


def draw_cases(scene: Scene, n: int, seed: int) -> list[tuple[float, float]]:
    """n (displacement_mm, angle_deg) pairs, uniform inside the envelope, from the first load step up."""
    sweep = scene.sweep
    envelope = Envelope.of_grid(sweep.displacements_mm, sweep.angles_deg)
    return envelope.sample(n, seed, min_displacement_mm=sweep.displacement_step_mm)


def case_file(out: Path, index: int) -> Path:
    return out / f"offgrid_{index:03d}.npz"


def grid_start(sweep: Path, grid: folder.Grid, d_mm: float, angle_deg: float) -> np.ndarray | None:
    """The sweep's field at (d, beta), bilinear between the four grid snapshots around it (n_dofs,);
    below the first grid displacement it is interpolated towards rest (zero). None when every weight
    falls on rest (d = 0)."""
    ds, bs = np.asarray([0.0, *grid.displacements_mm]), np.asarray(grid.angles_deg)
    j = int(np.clip(np.searchsorted(ds, d_mm) - 1, 0, len(ds) - 2))
    i = int(np.clip(np.searchsorted(bs, angle_deg) - 1, 0, max(len(bs) - 2, 0)))
    td = float(np.clip((d_mm - ds[j]) / (ds[j + 1] - ds[j]), 0.0, 1.0))
    tb = float(np.clip((angle_deg - bs[i]) / (bs[i + 1] - bs[i]), 0.0, 1.0)) if len(bs) > 1 else 0.0
    u = 0.0
    for ai, wb in ((i, 1.0 - tb), (min(i + 1, len(bs) - 1), tb)):
        for dj, wd in ((j, 1.0 - td), (j + 1, td)):
            if wb * wd == 0.0 or dj == 0:  # dj = 0: rest, zero
                continue
            with np.load(sweep / folder.snapshot_file(ai, dj - 1)) as z:
                u = u + wb * wd * z["displacement"].ravel()
    return np.asarray(u, dtype=np.float64) if np.ndim(u) else None


def solve_from(problem: Problem, start: np.ndarray, d_mm: float, angle_deg: float):
    """Newton at the guide position (d, beta) from `start` (n_dofs,), one step, no halving: (u, Stats).
    Raises ConvergenceError when that step does not converge."""
    (_, u, stats), = solve_path(problem.with_solver(max_halvings=0), [d_mm], angle_deg, state=PathState(start, d_mm))
    return u, stats


def _solve(problem: Problem, d_mm: float, angle_deg: float, sweep: str | None):
    """(u, Stats, how it started): from the sweep's interpolated field when given and path-solved, else from rest."""
    if sweep is not None and not problem.superposable:
        manifest = folder.read_manifest(sweep)
        start = grid_start(Path(sweep), manifest.grid, d_mm, angle_deg)
        if start is not None:
            try:
                u, stats = solve_from(problem, start, d_mm, angle_deg)
                return u, stats, "sweep"
            except ConvergenceError as exc:
                log.warning("%g mm, %g deg: the start from the sweep did not converge (%s); solving from rest",
                            d_mm, angle_deg, exc)
    u, stats = solve_case(problem, d_mm, angle_deg)
    return u, stats, "rest"


def solve_one(scene_json: str, mesh_path: str, out: str, index: int, d_mm: float, angle_deg: float,
              sweep: str | None = None) -> str | None:
    """Solve one case and write it; the error message if it did not converge."""
    from fem_offline.sweep import _check, _problem

    problem, t0 = _problem(scene_json, mesh_path), time.perf_counter()
    try:
        u, stats, started = _solve(problem, d_mm, angle_deg, sweep)
    except ConvergenceError as exc:
        return f"case {index} ({d_mm} mm, {angle_deg} deg): {exc}"
    stats = measured(problem, u, replace(stats, seconds=time.perf_counter() - t0))
    between = _check(scene_json, mesh_path)(u)  # between the solver's points, as a sweep's
    if not min(stats.min_det_f, *between.values()) > 0:
        log.warning("case %d (%g mm, %g deg): det(I + grad u) %.3g at the solver's points, %.3g at the probe points, "
                    "%.3g everywhere: an element is inside out", index, d_mm, angle_deg, stats.min_det_f,
                    between["min_det_f_probe"], between["min_det_f_bound"])
    folder.write_case(case_file(Path(out), index), u, displacement_mm=d_mm, angle_deg=angle_deg,
                      record=folder.CaseRecord(**stats.record(), **between),
                      reference_positions=problem.mesh.nodes, scene_sha256=problem.scene.sha256(), started_from=started)
    log.info("case %d: %g mm, %g deg, %d Newton iterations, %.1f s", index, d_mm, angle_deg, stats.iterations,
             stats.seconds)
    return None


def check_sweep_for_starts(scene: Scene, mesh_path: Path, sweep: Path) -> None:
    """Refuse a sweep whose physics or mesh differ from the cases' (its grid may extend further: a cut
    envelope is the same physics). ValueError naming `--sweep`."""
    from contracts.mesh import read_mesh

    manifest = folder.read_manifest(sweep)
    if manifest.scene.model_copy(update={"sweep": scene.sweep, "name": scene.name}) != scene:
        raise ValueError(f"--sweep: {sweep} is a sweep of another scene's physics; its fields cannot start these cases")
    if not np.array_equal(read_mesh(sweep / manifest.mesh).nodes, read_mesh(mesh_path).nodes):
        raise ValueError(f"--sweep: {sweep} is on another mesh than the cases (use its mesh.npz as --mesh)")
    if manifest.n_done < manifest.n_expected:
        raise ValueError(f"--sweep: {sweep} holds {manifest.n_done} of {manifest.n_expected} snapshots; "
                         "finish it first")


def solve_cases(scene: Scene, mesh_path: Path, out: Path, n: int, seed: int, *, workers: int = 2,
                sweep: Path | None = None) -> list[str]:
    """Solve the missing cases of the draw on a process pool; returns the failures. With `sweep` (the
    same scene's, on the same mesh) each case starts from the sweep's field around it (module docstring)."""
    from tqdm import tqdm

    from fem_offline.sweep import single_threaded_pool

    if sweep is not None:
        check_sweep_for_starts(scene, mesh_path, sweep)
    out.mkdir(parents=True, exist_ok=True)
    todo = [(i, d, a) for i, (d, a) in enumerate(draw_cases(scene, n, seed)) if not case_file(out, i).exists()]
    failures = []
    with single_threaded_pool(workers) as pool, tqdm(total=n, initial=n - len(todo), unit="case") as bar:
        futures = [pool.submit(solve_one, scene.model_dump_json(), str(mesh_path), str(out), *job,
                               sweep=None if sweep is None else str(sweep)) for job in todo]
        for f in futures:
            error = f.result()
            if error:
                failures.append(error)
            bar.update(1)
    return failures


def mesh_for_cases(mesh: TetMesh, out: Path) -> Path:
    """The cases' own mesh file, written once into `out`; every case is on its nodes."""
    from contracts.mesh import read_mesh, write_mesh

    path = out / folder.MESH_FILE
    if not path.exists():
        write_mesh(path, mesh)
    elif not np.array_equal(read_mesh(path).nodes, mesh.nodes):
        raise ValueError(f"--out: {out} holds cases on another mesh; use a new folder or the same --mesh")
    return path
