"""Off-grid cases started from the sweep (fem_offline cases --sweep) against the same case from rest.

    python -m studies warm-start-check --scene fem_offline/scenes/default_fine.toml --cases runs/default_v7/offgrid

Re-solves the case with the largest guide displacement (or --index) load-stepped from rest on the
cases' mesh, and prints how far the two equilibria are apart (markers, prostate surface, every
node) and what each cost. The physics is conservative, so they should agree within what the
solver's tolerances leave open (solver.rtol, guide.contact_tol_mm). With --model (a model folder
fitted on the same sweep) it also prints the surrogate's error against each of the two: its
off-grid error as measured with either start.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from contracts.mesh import read_mesh
from contracts.model import onnx_session
from fem_offline.fe.problem import build_problem
from fem_offline.geometry.regions import build_node_sets
from fem_offline.scene import load_scene
from fem_offline.fe.solve import solve_case


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies warm-start-check", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, required=True)
    ap.add_argument("--cases", type=Path, required=True, help="a `fem_offline cases --sweep` output folder")
    ap.add_argument("--index", type=int, help="case number (default: the largest displacement)")
    ap.add_argument("--model", type=Path, help="a model folder: its error against both starts' equilibria")
    args = ap.parse_args(argv)
    files = sorted(args.cases.glob("offgrid_*.npz"))
    cases = [dict(np.load(f)) for f in files]
    i = args.index if args.index is not None else int(np.argmax([float(c["displacement_mm"]) for c in cases]))
    case = cases[i]
    if str(case.get("started_from", "rest")) != "sweep":
        raise SystemExit(f"{files[i]}: not started from the sweep (started_from = {case.get('started_from')})")
    d, beta = float(case["displacement_mm"]), float(case["angle_deg"])
    scene = load_scene(args.scene)
    mesh = build_node_sets(read_mesh(args.cases / "mesh.npz"), scene)
    problem = build_problem(scene, mesh)
    print(f"{files[i].name}: {d:.3f} mm, {beta:.3f} deg; from the sweep: {int(case['newton_iterations'])} Newton "
          f"iterations, {int(case['factorizations'])} factorisations, {float(case['seconds']):.1f} s", flush=True)
    u, stats = solve_case(problem, d, beta)
    print(f"from rest: {stats.iterations} Newton iterations, {stats.factorizations} factorisations, "
          f"{stats.seconds:.1f} s")
    gap = np.linalg.norm(u - case["displacement"], axis=1)
    for name, ids in (("markers", mesh.node_sets["markers"]), ("prostate surface", mesh.node_sets["prostate_surface"]),
                      ("every node", slice(None))):
        print(f"  {name}: max |u_sweep start - u_rest| {gap[ids].max():.2e} mm (max |u| "
              f"{np.linalg.norm(u, axis=1)[ids].max():.3f} mm)")
    if args.model is not None:
        session = onnx_session(args.model / "model.onnx")
        pred = session.run(None, {"guide": np.array([[d, beta]], dtype=np.float32)})[0][0]
        for label, fe in (("from the sweep", case["displacement"]), ("from rest", u)):
            err = np.linalg.norm(pred - fe, axis=1)
            print(f"  surrogate ({args.model}) vs the case {label}: max over nodes (e_NN) {err.max():.4f} mm, "
                  f"markers {err[mesh.node_sets['markers']].max():.4f} mm")
