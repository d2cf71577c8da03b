"""Material cases: fresh FE solves at held-out stiffnesses, to check the first-order material model.

At each guide position (d, beta) the nominal scene is solved (u0) with its sensitivities S_i = du/d ln E_i
(fe.sensitivity), then the scene with the material tissues' E set to each material point is solved afresh.
The points: every tissue at both ends of its declared range with the others nominal, then two corners where the
tissues alternate between their ends (upper, lower, upper, ... and the reverse; theta_i = ln(E_i / E_i,nominal)).
All at their lower or all at their upper ends would change no ratio, and so (nearly) nothing (fe/sensitivity.py). A
fresh solve is a continuation in the materials at the final guide position: Newton from the nominal equilibrium plus the
first-order change u0 + sum_i S_i theta_i (with the nominal contact multipliers), else in 2 or 4 steps of theta,
else the path from rest; the equilibrium does not depend on the start (cases.py). A point where none converges is
kept as a finding (NaN, its message in `failures`) and the check counts it. With --sweep, the S_i are the
material sweep's own snapshot at that position (the fields the model was fitted on) and u0 that snapshot solved
again as the fresh states are, instead of solving both from rest. One file per guide position
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

from fem_offline.fe.continuation import PathState, solve_path
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
    ends = np.array([[np.log(e / scene.tissues[t].youngs) for e in scene.materials[t].youngs_kpa_range]
                     for t in tissues])
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


def _at(scene: Scene, mesh: TetMesh, d_mm: float, angle_deg: float, start: np.ndarray, multipliers):
    """(u (n_nodes, 3), contact multipliers) of `scene` at (d, beta): Newton from `start` with `multipliers`, no
    halving. Raises ConvergenceError."""
    problem = build_problem(scene, mesh).with_solver(max_halvings=0)
    (_, u, _, state), = list(solve_path(problem, [d_mm], angle_deg, with_state=True,
                                        state=PathState(np.ravel(start).copy(), d_mm, multipliers=multipliers)))
    return u, state.multipliers


CONTINUATION_STEPS = (1, 2, 4)


def _fresh(scene: Scene, mesh: TetMesh, tissues: tuple[str, ...], theta: np.ndarray, nominal,
           sens: dict[str, np.ndarray], d_mm: float, angle_deg: float) -> np.ndarray:
    """Equilibrium (n_nodes, 3) of the scene with E_i scaled by exp(theta_i) at (d, beta), from the nominal
    equilibrium `nominal` = (u0, contact multipliers) at the same guide position.

    A continuation in the materials at the final guide position, in 1, 2, then 4 steps: each step starts Newton
    from the last equilibrium plus the first-order change S . (theta / k), with its contact multipliers. Else
    load-stepped from rest. Raises ConvergenceError when none converges."""
    shift = sum(sens[n] * v for n, v in zip(tissues, theta))
    for k in CONTINUATION_STEPS:
        u, multipliers = nominal
        try:
            for j in range(1, k + 1):
                u, multipliers = _at(scaled_scene(scene, tissues, theta * j / k), mesh, d_mm, angle_deg, u + shift / k,
                                     multipliers)
            return u
        except ConvergenceError as exc:
            log.warning("%g mm, %g deg, theta %s: not in %d step(s) from the nominal state (%s)",
                        d_mm, angle_deg, np.round(theta, 3), k, exc)
    return solve_case(build_problem(scaled_scene(scene, tissues, theta), mesh), d_mm, angle_deg)[0]


def nominal_from_sweep(sweep: Path, tissues: tuple[str, ...], d_mm: float, angle_deg: float):
    """(u0 (n_nodes, 3), {tissue: S_i}) of a material sweep's snapshot at exactly (d, beta)."""
    from contracts.sweep import read_manifest, snapshot_file

    try:
        grid = read_manifest(sweep).grid
    except (FileNotFoundError, ValueError) as exc:
        raise ValueError(f"--sweep: {exc}") from None
    hit = [(i, j) for i, a in enumerate(grid.angles_deg) for j, d in enumerate(grid.displacements_mm)
           if abs(a - angle_deg) < 1e-9 and abs(d - d_mm) < 1e-9]
    if not hit:
        raise ValueError(f"--case {d_mm:g}/{angle_deg:g}: not a snapshot of the sweep {sweep}")
    with np.load(Path(sweep) / snapshot_file(*hit[0])) as z:
        missing = [t for t in tissues if sensitivity_key(t) not in z.files]
        if missing:
            raise ValueError(f"--sweep: {sweep} holds no sensitivities of {missing}: "
                             "not a sweep of this scene's [materials]")
        return z["displacement"], {t: z[sensitivity_key(t)] for t in tissues}


def solve_material_case(scene: Scene, mesh: TetMesh, d_mm: float, angle_deg: float, out: Path,
                        sweep: Path | None = None) -> Path:
    """Solve one guide position's nominal state, sensitivities and fresh material points; write `out` (.npz).
    With `sweep` (a material sweep of the scene on `mesh`), the nominal state and S_i are its snapshot's."""
    if out.exists():
        return out
    tissues, theta = material_points(scene)
    problem = build_problem(scene, mesh)
    if sweep is not None and not problem.superposable:
        snapshot, sens = nominal_from_sweep(sweep, tissues, d_mm, angle_deg)
        # u0 solved again from the snapshot as the fresh states are (no contact multipliers to start with), so
        # the first-order error holds no difference of contact tolerance between the sweep's path and these solves
        nominal = _at(scene, mesh, d_mm, angle_deg, snapshot, None)
    elif sweep is not None:
        u0, sens = nominal_from_sweep(sweep, tissues, d_mm, angle_deg)
        nominal = (u0, None)
    else:
        (d, u0, _, state), = list(solve_path(problem, [d_mm], angle_deg, with_state=True))
        sens = sensitivities(stiffened(problem, tissues), problem.at_guide(d, angle_deg, state.multipliers), state.u)
        nominal = (u0, state.multipliers)
    fresh, failures = [], []
    for t in theta:
        try:
            fresh.append(_fresh(scene, mesh, tissues, t, nominal, sens, d_mm, angle_deg))
            failures.append("")
            log.info("%g mm, %g deg, theta %s: solved", d_mm, angle_deg, np.round(t, 3))
        except ConvergenceError as exc:  # kept as a finding: the check counts it and says which point
            fresh.append(np.full_like(nominal[0], np.nan))
            failures.append(str(exc))
            log.warning("%g mm, %g deg, theta %s: no equilibrium found (%s)", d_mm, angle_deg, np.round(t, 3), exc)
    atomic_savez(out, displacement=nominal[0], displacement_mm=d_mm, angle_deg=angle_deg, tissues=np.array(tissues),
                 theta=theta, fresh=np.stack(fresh), failures=np.array(failures),
                 **{sensitivity_key(n): s for n, s in sens.items()})
    return out


def default_positions(scene: Scene) -> list[tuple[float, float]]:
    """The hardest guide positions of the grid for a first-order model: the largest push at beta = 0 and at the
    largest angle (the answer moves most there)."""
    d = float(scene.sweep.displacements_mm[-1])
    return [(d, 0.0), (d, float(scene.sweep.angles_deg[-1]))]


def solve_material_cases(scene: Scene, mesh: TetMesh, out: Path, positions: list[tuple[float, float]], *,
                         workers: int = 2, sweep: Path | None = None) -> list[Path]:
    """Every guide position's material case on a process pool (one position per worker); the files, in order."""
    from fem_offline.sweep import single_threaded_pool

    if sweep is not None:  # every position a snapshot with the sensitivities, before any solve
        for d, a in positions:
            u0, _ = nominal_from_sweep(sweep, material_points(scene)[0], d, a)
            if u0.shape != mesh.nodes.shape:
                raise ValueError(f"--sweep: {sweep} is on a mesh of {len(u0)} nodes, --mesh has {len(mesh.nodes)}")
    out.mkdir(parents=True, exist_ok=True)
    files = [out / f"material_{i:03d}.npz" for i in range(len(positions))]
    with single_threaded_pool(min(workers, len(positions))) as pool:
        jobs = [pool.submit(solve_material_case, scene, mesh, d, a, f, sweep) for (d, a), f in zip(positions, files)]
        return [j.result() for j in jobs]
