"""Benchmark the offline FE on a scene: mesh size, assembly, linear and nonlinear solve times.

    python -m bench fem [--scene fem_offline/scenes/default.toml] [--steps 12] [--sweep runs/default]
    python -m bench fem --scene fem_offline/scenes/paper_scale.toml --mesh runs/paper/mesh.npz --steps 2

Prints medians measured in this run; with --sweep it also reads a finished sweep's manifest for
the measured full-sweep time. Not a test: the numbers depend on the machine and its load.
Run it with MKL_NUM_THREADS=1 (`make bench` does): one core per path, as the sweep runs.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from statistics import median

import numpy as np

from fem_offline.fe import elasticity as el
from fem_offline.fe.continuation import solve_path
from fem_offline.fe.linear import linear_modes, min_det_f, superpose
from fem_offline.fe.linsolve import AMG_MIN_DOFS
from fem_offline.geometry.mesh import skfem_mesh
from fem_offline.geometry.meshing import load_or_build_mesh
from fem_offline.fe.problem import build_problem
from fem_offline.scene import load_scene
from fem_offline.fe.validity import PROBE_INTORDER, points_per_tet, probe

from bench._report import Report
from studies import results


def timed(fn, repeat=1):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return median(times), out


def skfem_assembly_seconds(problem) -> float:
    """scikit-fem's own BilinearForm for the same operator, for comparison with the einsum kernel."""
    from skfem import Basis, BilinearForm, ElementTetP2, ElementVector, asm
    from skfem.helpers import ddot, div, sym_grad

    from fem_offline.fe.materials import lame

    mesh = problem.mesh
    mu, lam, _ = lame(problem.scene, mesh)
    basis = Basis(skfem_mesh(mesh), ElementVector(ElementTetP2()), intorder=2)

    @BilinearForm
    def linear_elasticity(u, v, w):
        return w.lam * div(u) * div(v) + 2.0 * w.mu * ddot(sym_grad(u), sym_grad(v))

    nq = basis.dx.shape[1]
    t0 = time.perf_counter()
    asm(linear_elasticity, basis, lam=np.repeat(lam[:, None], nq, 1), mu=np.repeat(mu[:, None], nq, 1))
    return time.perf_counter() - t0


def probe_cost(problem, lin_problem, modes, u: np.ndarray, scene) -> str:
    """What the sweep's det F probe (validity.probe) adds: its basis, and per snapshot, nonlinear and linear."""
    t_basis, probed = timed(lambda: probe(problem), repeat=3)
    t4, _ = timed(lambda: problem.min_jacobian(u), repeat=5)
    t11, _ = timed(lambda: probed.min_jacobian(u), repeat=5)
    lin_probed, d = probe(lin_problem), scene.sweep.displacements_mm
    n_cases = len(scene.sweep.angles_deg) * len(d)
    c4, _ = timed(lambda: [min_det_f(lin_problem, modes, d, b) for b in scene.sweep.angles_deg])
    c11, _ = timed(lambda: [min_det_f(lin_probed, modes, d, b) for b in scene.sweep.angles_deg])
    return (f"det F probe ({points_per_tet(PROBE_INTORDER)} points per tet, recorded with every snapshot): basis "
            f"{t_basis:.2f} s once per process; per nonlinear snapshot {1e3 * t11:.1f} ms (4 points: {1e3 * t4:.1f} "
            f"ms); per linear snapshot by det F's cubic {1e3 * c11 / n_cases:.2f} ms (4 points: "
            f"{1e3 * c4 / n_cases:.2f} ms)")


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m bench fem", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=Path("fem_offline/scenes/grid_study_base.toml"))
    ap.add_argument("--steps", type=int, default=12, help="nonlinear load steps timed on the beta = 10 deg path")
    ap.add_argument("--sweep", type=Path, help="a finished sweep folder to read the measured sweep time from")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--mesh", type=Path, help="reuse a saved mesh (.vtu) instead of meshing with gmsh")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    say = Report()

    scene = load_scene(args.scene)
    t_mesh, mesh = timed(lambda: load_or_build_mesh(scene, args.mesh))
    t_prep, problem = timed(lambda: build_problem(scene, mesh))
    n_cases = len(scene.sweep.angles_deg) * len(scene.sweep.displacements_mm)
    large = problem.free.size >= AMG_MIN_DOFS  # AMG-CG, not PARDISO; minutes per solve
    say(f"scene {scene.name}: {len(mesh.tets)} tets, {len(mesh.nodes)} nodes, {3 * len(mesh.nodes)} DOFs "
          f"({problem.free.size} free); {'mesh read' if args.mesh else 'gmsh'} {t_mesh:.1f} s, preparation "
          f"{t_prep:.1f} s")

    t_einsum, _ = timed(lambda: el.linear_stiffness(problem.G, problem.W, problem.mu, problem.lam), repeat=3)
    skfem = "skipped (too large)" if large else f"{skfem_assembly_seconds(problem):.2f} s"
    say(f"element stiffness: einsum kernel {t_einsum:.2f} s, scikit-fem BilinearForm {skfem}")

    lin = scene.model_copy(update={"effects": scene.effects.model_copy(update={"geometric_nonlinearity": False})})
    lin_problem = build_problem(lin, mesh)
    t_lin, modes = timed(lambda: linear_modes(lin_problem), repeat=1 if large else 3)
    t_sup, _ = timed(lambda: [superpose(modes, scene.sweep.displacements_mm, b) for b in scene.sweep.angles_deg])
    how = "AMG setup + 2 unit solves, once" if large else "factorise + 2 unit solves, median of 3"
    say(f"linear: {t_lin:.2f} s per solve ({how}); all {n_cases} cases by superposition "
          f"{t_lin + t_sup:.2f} s")

    steps = list(solve_path(problem, scene.sweep.displacements_mm[: args.steps], 10.0))
    secs = [s.seconds for _, _, s in steps]
    its = [s.iterations for _, _, s in steps]
    per = median(secs)
    say(f"nonlinear: median {per:.2f} s per snapshot (mean {np.mean(secs):.2f}), Newton iterations median "
          f"{median(its)} (max {max(its)}), min det F {steps[-1][2].min_det_f:.3f} at {steps[-1][0]} mm, beta 10 deg, "
          f"first {len(steps)} steps")
    say(probe_cost(problem, lin_problem, modes, steps[-1][1].ravel(), scene))
    say(f"projected nonlinear sweep: {n_cases} x {np.mean(secs):.2f} s / {args.workers} workers = "
          f"{n_cases * np.mean(secs) / args.workers / 60:.1f} min")
    n_path = len(scene.sweep.displacements_mm)
    say(f"projected single snapshot at {scene.sweep.displacements_mm[-1]} mm from rest: {n_path} load steps x "
          f"{np.mean(secs):.1f} s = {n_path * np.mean(secs) / 60:.1f} min")
    if args.sweep:
        m = json.loads((args.sweep / "manifest.json").read_text())
        rows = m["snapshots"]
        say(f"measured sweep {args.sweep}: {m['n_done']}/{m['n_expected']} snapshots in "
              f"{m['wall_seconds_this_run'] / 60:.1f} min wall; per snapshot median "
              f"{median(r['seconds'] for r in rows):.2f} s, Newton iterations median "
              f"{median(r['newton_iterations'] for r in rows)} max {max(r['newton_iterations'] for r in rows)}; min "
              f"det F {min(r['min_det_f'] for r in rows):.3f}; failures {len(m['errors'])}")
    print(f"wrote {results.write('bench_fem', {'lines': say.lines}, publish=args.publish)}")
    return 0
