"""Material cases: fresh FE solves at held-out stiffnesses, to check the first-order material model.

At each guide position (d, beta) the nominal scene is solved (u0) with its sensitivities S_i = du/d ln E_i
(fe.sensitivity), then the scene with the material tissues' E set to each material point is solved afresh.
The points: every tissue at both ends of its declared range with the others nominal, then two corners where the
tissues alternate between their ends (upper, lower, upper, ... and the reverse; theta_i = ln(E_i / E_i,nominal)).
All at their lower or all at their upper ends would change no ratio, and so (nearly) nothing (fe/sensitivity.py). A fresh solve starts Newton
from the first-order answer u0 + sum_i S_i theta_i at the final guide position and falls back to the path
from rest; the equilibrium does not depend on the start (cases.py). One file per guide position
(`material_NNN.npz`): displacement (u0), displacement_mm, angle_deg, sensitivity_<tissue>, tissues, theta
(p, m) and fresh (p, n_nodes, 3); `training material-check` reads them (training/materials.py). Resumable:
a finished file is kept.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from contracts.files import atomic_savez
from contracts.materials import sensitivity_key
from contracts.mesh import TetMesh

from fem_offline.cases import solve_from
from fem_offline.fe.continuation import solve_path
from fem_offline.fe.newton import ConvergenceError
from fem_offline.fe.problem import build_problem
from fem_offline.fe.sensitivity import sensitivities, stiffened
from fem_offline.fe.solve import solve_case
from fem_offline.scene import Scene

log = logging.getLogger(__name__)


def material_points(scene: Scene) -> tuple[tuple[str, ...], np.ndarray]:
    """(tissues, theta (p, m)): each tissue at both ends of its range, then the two alternating corners."""
    if not scene.materials:
        raise ValueError("--scene: the scene has no [materials]; there is nothing to check")
    tissues = tuple(scene.materials)
    ends = np.array([[np.log(e / scene.tissues[t].youngs) for e in scene.materials[t].youngs_kpa_range] for t in tissues])
    rows = [np.eye(len(tissues))[i] * ends[i, j] for i in range(len(tissues)) for j in (0, 1)]
    alternate = np.arange(len(tissues)) % 2  # 0, 1, 0, ...: lower, upper, lower, ...
    corners = [ends[np.arange(len(tissues)), alternate], ends[np.arange(len(tissues)), 1 - alternate]]
    return tissues, np.array(rows + corners)


def scaled_scene(scene: Scene, tissues: tuple[str, ...], theta: np.ndarray) -> Scene:
    """The scene with E_i = E_i,nominal exp(theta_i) for each listed tissue."""
    changed = dict(scene.tissues)
    for name, t in zip(tissues, theta):
        changed[name] = scene.tissues[name].model_copy(
            update={"youngs_kpa": scene.tissues[name].youngs * float(np.exp(t)), "shear_wave_speed_m_s": None})
    return scene.model_copy(update={"tissues": changed})


def _fresh(scene: Scene, mesh: TetMesh, start: np.ndarray, d_mm: float, angle_deg: float) -> np.ndarray:
    """Equilibrium (n_nodes, 3) of `scene` at (d, beta): Newton from `start`, else load-stepped from rest."""
    problem = build_problem(scene, mesh)
    if not problem.superposable:
        try:
            return solve_from(problem, start.ravel(), d_mm, angle_deg)[0]
        except ConvergenceError as exc:
            log.warning("%g mm, %g deg: the first-order start did not converge (%s); solving from rest", d_mm, angle_deg, exc)
    return solve_case(problem, d_mm, angle_deg)[0]


def solve_material_case(scene: Scene, mesh: TetMesh, d_mm: float, angle_deg: float, out: Path) -> Path:
    """Solve one guide position's nominal state, sensitivities and fresh material points; write `out` (.npz)."""
    if out.exists():
        return out
    tissues, theta = material_points(scene)
    problem = build_problem(scene, mesh)
    (d, u0, _, state), = list(solve_path(problem, [d_mm], angle_deg, with_state=True))
    sens = sensitivities(stiffened(problem, tissues), problem.at_guide(d, angle_deg, state.multipliers), state.u)
    fresh = []
    for t in theta:
        start = u0 + sum(sens[n] * v for n, v in zip(tissues, t))
        fresh.append(_fresh(scaled_scene(scene, tissues, t), mesh, start, d_mm, angle_deg))
        log.info("%g mm, %g deg, theta %s: solved", d_mm, angle_deg, np.round(t, 3))
    atomic_savez(out, displacement=u0, displacement_mm=d_mm, angle_deg=angle_deg, tissues=np.array(tissues),
                 theta=theta, fresh=np.stack(fresh), **{sensitivity_key(n): s for n, s in sens.items()})
    return out


def default_positions(scene: Scene) -> list[tuple[float, float]]:
    """The hardest guide positions of the grid for a first-order model: the largest push at beta = 0 and at the
    largest angle (the answer moves most there)."""
    d = float(scene.sweep.displacements_mm[-1])
    return [(d, 0.0), (d, float(scene.sweep.angles_deg[-1]))]


def solve_material_cases(scene: Scene, mesh: TetMesh, out: Path, positions: list[tuple[float, float]], *,
                         workers: int = 2) -> list[Path]:
    """Every guide position's material case on a process pool (one position per worker); the files, in order."""
    from fem_offline.sweep import single_threaded_pool

    out.mkdir(parents=True, exist_ok=True)
    files = [out / f"material_{i:03d}.npz" for i in range(len(positions))]
    with single_threaded_pool(min(workers, len(positions))) as pool:
        jobs = [pool.submit(solve_material_case, scene, mesh, d, a, f) for (d, a), f in zip(positions, files)]
        return [j.result() for j in jobs]
