"""Command line: `python -m fem_offline solve|sweep|design|cases|material-cases|mesh ...`; bad input gets one line,
exit code 2."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

from contracts.cli import number

from fem_offline.scene import SceneError, load_scene


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m fem_offline", description=__doc__)
    ap.add_argument("-v", "--verbose", action="store_true", help="log solver progress")
    sub = ap.add_subparsers(dest="command", required=True)

    s = sub.add_parser("solve", help="solve one (displacement, angle) case")
    s.add_argument("--scene", required=True, type=Path)
    s.add_argument("--displacement-mm", required=True, type=number("--displacement-mm"))
    s.add_argument("--angle-deg", required=True, type=number("--angle-deg"))
    s.add_argument("--out", required=True, type=Path, help="output .npz")
    s.add_argument("--mesh", type=Path, help="reuse a saved mesh (e.g. a sweep's mesh.vtu)")
    s.add_argument("--step-mm", type=number("--step-mm"), help="load step (default: the sweep's step)")

    w = sub.add_parser("sweep", help="solve the scene's whole grid (resumable)")
    w.add_argument("--scene", required=True, type=Path)
    w.add_argument("--out", required=True, type=Path, help="output folder")
    w.add_argument("--workers", type=number("--workers", int, minimum=1), default=2,
                   help="local processes, one path each (default 2)")
    w.add_argument("--scheduler", help="Dask scheduler address tcp://host:port (default: local pool)")

    g = sub.add_parser("design", help="paths at space-filling points in (beta, stiffness ratios) over the scene's "
                       "material box, for a model right over the whole box (resumable)")
    g.add_argument("--scene", required=True, type=Path, help="a scene with [materials] (the box)")
    g.add_argument("--out", required=True, type=Path, help="output folder (design.json, one sweep folder per point)")
    g.add_argument("--n", type=number("--n", int, minimum=1), default=64, help="number of points (default 64)")
    g.add_argument("--seed", type=number("--seed", int), default=0,
                   help="seed of the scrambled Sobol sequence (default 0)")
    g.add_argument("--mesh", type=Path,
                   help="solve on this mesh (.npz, e.g. models/default/mesh.npz; default: mesh the scene)")
    g.add_argument("--held-out", action="store_true", help="the box's corners first, then Sobol points, all at the "
                   "largest angle and without sensitivities: a set to check a model against")
    g.add_argument("--sensitivities", action=argparse.BooleanOptionalAction, default=None,
                   help="store S_i = du/d ln E_i at every snapshot (default: yes, no with --held-out)")
    g.add_argument("--sensitivity-every", type=number("--sensitivity-every", int, minimum=1), default=4,
                   help="S_i at every this-many-th displacement of a path (default 4: every mm at 0.25 mm steps)")
    g.add_argument("--workers", type=number("--workers", int, minimum=1), default=2,
                   help="local processes, one path each (default 2)")
    g.add_argument("--scheduler", help="Dask scheduler address tcp://host:port (default: local pool)")
    g.add_argument("--push-step", type=number("--push-step", minimum=0), default=None, metavar="MM",
                   help="push step of every path (default: the scene's); a held-out set needs only the equilibria, "
                        "so a coarser step (e.g. 1) solves it in fewer steps, halved where one fails")

    c = sub.add_parser("cases",
                       help="solve random off-grid cases inside the sweep's envelope (held-out set; resumable)")
    c.add_argument("--scene", required=True, type=Path)
    c.add_argument("--out", required=True, type=Path, help="output folder (offgrid_NNN.npz + mesh.npz)")
    c.add_argument("--n", type=number("--n", int, minimum=1), default=24, help="number of cases (default 24)")
    c.add_argument("--seed", type=number("--seed", int), default=0, help="random seed of the draw (default 0)")
    c.add_argument("--mesh", type=Path,
                   help="the sweep's mesh.npz, so the cases share its nodes (default: mesh the scene)")
    c.add_argument("--workers", type=number("--workers", int, minimum=1), default=2,
                   help="local processes, one case each (default 2)")
    c.add_argument("--sweep", type=Path, help="a finished sweep of the same scene on the same mesh: start each case "
                   "from its fields around it instead of load-stepping from rest (same equilibrium; default: "
                   "from rest)")

    k = sub.add_parser("material-cases", help="fresh solves at the ends of the scene's material ranges, to check the "
                       "first-order material model (training material-check; resumable)")
    k.add_argument("--scene", required=True, type=Path)
    k.add_argument("--out", required=True, type=Path, help="output folder (material_NNN.npz)")
    k.add_argument("--mesh", type=Path, help="the sweep's mesh.npz (default: mesh the scene)")
    k.add_argument("--case", action="append", help="guide position D/A in mm/deg (repeatable; default: the largest "
                   "push at 0 deg and at the largest angle)")
    k.add_argument("--workers", type=number("--workers", int, minimum=1), default=2, help="local processes (default 2)")
    k.add_argument("--sweep", type=Path, help="the scene's material sweep on the same mesh: its snapshots give the "
                   "nominal state and sensitivities at each --case (a grid point), instead of solving them again")

    m = sub.add_parser("mesh", help="mesh the scene and write it (.npz, .vtu, .msh or .xdmf)")
    m.add_argument("--scene", required=True, type=Path)
    m.add_argument("--out", required=True, type=Path)
    return ap


def _solve(args) -> None:
    from contracts import sweep as folder

    from fem_offline.fe.linear import measured
    from fem_offline.geometry.meshing import load_or_build_mesh
    from fem_offline.fe.problem import build_problem
    from fem_offline.fe.solve import solve_case
    from fem_offline.fe.validity import DetFCheck

    if args.out.suffix != ".npz":
        raise ValueError(f"--out: must end in .npz, got {args.out}")
    if args.step_mm is not None and args.step_mm <= 0:
        raise ValueError("--step-mm: must be positive")
    scene = load_scene(args.scene)
    mesh = load_or_build_mesh(scene, args.mesh)
    problem = build_problem(scene, mesh)
    u, stats = solve_case(problem, args.displacement_mm, args.angle_deg, step_mm=args.step_mm)
    stats = measured(problem, u, stats)
    between = DetFCheck.of(problem)(u)  # between the solver's points, as a sweep's snapshots
    at_probe, bound = between["min_det_f_probe"], between["min_det_f_bound"]
    folder.write_case(args.out, u, displacement_mm=args.displacement_mm, angle_deg=args.angle_deg,
                      record=folder.CaseRecord(**stats.record(), **between), reference_positions=mesh.nodes,
                      scene_sha256=scene.sha256())
    print(
        f"{args.out}: {len(mesh.nodes)} nodes, max |u| {np.linalg.norm(u, axis=1).max():.4f} mm, "
        f"{stats.iterations} Newton iterations, min det F {stats.min_det_f:.3f} ({at_probe:.3f} at the probe points, "
        f"{'at least ' if bound > 0 else ''}{bound:.3f} everywhere), "
        f"{stats.seconds:.1f} s"
    )
    if not min(stats.min_det_f, at_probe, bound) > 0:
        print(f"warning: det(I + grad u) {min(stats.min_det_f, at_probe, bound):.3g} <= 0: the solution turns an "
              "element inside out at this displacement; the case is written but is not a deformation", file=sys.stderr)


def _sweep(args) -> int:
    from fem_offline.sweep import run_sweep

    if args.scheduler and not args.scheduler.startswith(("tcp://", "tls://", "inproc://", "ucx://")):
        raise ValueError(f"--scheduler: expected an address like tcp://host:8786, got {args.scheduler!r}")
    manifest = run_sweep(load_scene(args.scene), args.out, workers=args.workers, scheduler=args.scheduler)
    print(f"{args.out}: {manifest.n_done}/{manifest.n_expected} snapshots, "
          f"{manifest.wall_seconds_this_run:.1f} s this run")
    if manifest.validity.n_inverted:
        print(_inversion_warning(manifest), file=sys.stderr)
    if manifest.validity.n_unprobed:
        print(f"note: {manifest.validity.n_unprobed} snapshots were written before det F was probed between the "
              "quadrature points (sweep format 2); they are judged at the solver's points only", file=sys.stderr)
    elif manifest.validity.n_unbounded:
        print(f"note: {manifest.validity.n_unbounded} snapshots were written before det F was bounded everywhere "
              "(sweep format 3); they are judged at their 15 points per tet only", file=sys.stderr)
    for err in manifest.errors:
        print(f"failed: {err}", file=sys.stderr)
    return 1 if manifest.errors else 0


def _design(args) -> int:
    from fem_offline.design import run_design

    if args.scheduler and not args.scheduler.startswith(("tcp://", "tls://", "inproc://", "ucx://")):
        raise ValueError(f"--scheduler: expected an address like tcp://host:8786, got {args.scheduler!r}")
    if args.mesh is not None and not args.mesh.exists():
        raise ValueError(f"--mesh: no such file {args.mesh}")
    sensitivities = (not args.held_out) if args.sensitivities is None else args.sensitivities
    summary = run_design(load_scene(args.scene), args.out, n=args.n, seed=args.seed, sensitivities=sensitivities,
                         sensitivity_every=args.sensitivity_every, held_out=args.held_out, mesh=args.mesh,
                         workers=args.workers, scheduler=args.scheduler, step_mm=args.push_step)
    print(f"{args.out}: {summary['finished']}/{summary['points']} points finished, {summary['snapshots']}/"
          f"{summary['expected']} snapshots, {summary['seconds']:.0f} s this run")
    for where, errors in summary["stopped"].items():
        for err in errors:
            print(f"stopped: {where}: {err}", file=sys.stderr)
    return 1 if summary["stopped"] else 0


def _inversion_warning(manifest) -> str:
    """The sweep's warning for snapshots with det(I + grad u) <= 0 (SweepManifest.validity)."""
    v = manifest.validity
    firsts = sorted({d for d in v.first_inverted_mm if d is not None})
    first = f"{firsts[0]:g} mm" if len(firsts) == 1 else f"{firsts[0]:g} to {firsts[-1]:g} mm depending on the angle"
    return (f"warning: {v.n_inverted} of {manifest.n_done} snapshots turn an element inside out (det(I + grad u) <= 0 "
            f"somewhere in a tet, min {v.min_det_f:.3g}), the first at {first}. They are "
            f"written, and listed under `validity` in manifest.json. Every angle is valid up to {v.valid_up_to_mm:g} "
            f"mm; `training fit` fits and serves only that part.")


def _cases(args) -> int:
    from fem_offline.cases import mesh_for_cases, solve_cases
    from fem_offline.geometry.meshing import load_or_build_mesh

    scene = load_scene(args.scene)
    args.out.mkdir(parents=True, exist_ok=True)
    mesh_path = mesh_for_cases(load_or_build_mesh(scene, args.mesh), args.out)
    failures = solve_cases(scene, mesh_path, args.out, args.n, args.seed, workers=args.workers, sweep=args.sweep)
    print(f"{args.out}: {args.n - len(failures)}/{args.n} cases solved (seed {args.seed})")
    for err in failures:
        print(f"failed: {err}", file=sys.stderr)
    return 1 if failures else 0


def _material_cases(args) -> int:
    from fem_offline.geometry.meshing import load_or_build_mesh
    from fem_offline.material_cases import default_positions, solve_material_cases

    scene = load_scene(args.scene)
    try:
        positions = ([tuple(float(v) for v in c.split("/")) for c in args.case] if args.case
                     else default_positions(scene))
    except ValueError:
        raise ValueError(f"--case: expected DISPLACEMENT_MM/ANGLE_DEG like 10/0, got {args.case}") from None
    files = solve_material_cases(scene, load_or_build_mesh(scene, args.mesh), args.out, positions, workers=args.workers,
                                 sweep=args.sweep)
    print(f"{args.out}: {len(files)} guide positions, each at {2 * len(scene.materials or {}) + 2} material points")
    return 0


def _mesh(args) -> None:
    from fem_offline.geometry.mesh import save
    from fem_offline.geometry.meshing import mesh_for_scene

    if args.out.suffix not in (".npz", ".vtu", ".msh", ".xdmf"):
        raise ValueError(f"--out: use .npz, .vtu, .msh or .xdmf, got {args.out.suffix or 'no suffix'}")
    mesh = mesh_for_scene(load_scene(args.scene))
    save(mesh, args.out)
    print(f"{args.out}: {len(mesh.tets)} tets, {len(mesh.nodes)} nodes, {3 * len(mesh.nodes)} DOFs")


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    from fem_offline.fe.newton import ConvergenceError

    try:
        return {"solve": _solve, "sweep": _sweep, "design": _design, "cases": _cases, "material-cases": _material_cases,
                "mesh": _mesh}[args.command](args) or 0
    except (SceneError, ValueError, ConvergenceError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: finished snapshots are kept; run the same command again to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
