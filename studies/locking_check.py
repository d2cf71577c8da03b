"""Why the grid-convergence study's fifth level moved the markers outward: volumetric locking or not.

    MKL_NUM_THREADS=2 python -m studies locking-check [--scales 1.3 1 0.769 0.5917 0.455]
        [--poisson 0.495 0.45] [--case 2 0] [--volumetric pointwise] [--rtol 1e-8] [--contact-tol-mm 0.0005]
        [--meshes runs/convergence_resolve] [--out runs/locking] [--publish]

The nonlinear study's markers grow with every refinement (the finer mesh is softer), and the fifth
level moved them more than the fourth. Volumetric locking of the P2 tets at nu = 0.495 would do
that: a discretisation that is too stiff in near-incompressible tissue, relieved as h shrinks. It
can be seen without the nonlinear paths, which take an hour a path on a sixth level here: the
same scene and meshes with small-strain elasticity (the guide still in frictionless contact, a push
small enough for the linear model to stay valid) take seconds a level, so the study can go one or
two levels finer. Each level is solved at the scene's nu (0.495) and at a compressible one (0.45):
if the convergence at 0.45 is orderly and at 0.495 is not, the cause is locking; if both look alike,
it is the mesh family (e.g. thin parts that the coarse levels cannot make coarser). Every level's
meshes are the study's own (--meshes, reused when there) or made at sizes x scale.

Also per level: the tet count and its ratio to the next (a geometric family refined by r has r^3
more tets) and each tissue's median tet edge, to see whether every part of the mesh refines by r.

--volumetric mean_dilatation solves the same levels with the volumetric term taken per tet
(solver.volumetric, fem_offline/fe/elasticity.py), a first remedy; --volumetric taylor_hood with a P1
pressure per tissue (P2/P1, fem_offline/fe/mixed.py), one that keeps the P2 element's order.

Each (nu, level) result is written to --out as it finishes; a rerun resumes. The table and the
GCI of the three finest levels per nu are the result locking_check_<volumetric> (with _nu045 when
--poisson is 0.45 alone, say), in runs/results/ or, with --publish, docs/results/.
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import time
from pathlib import Path

import numpy as np

from contracts.mesh import read_mesh, write_mesh
from fem_offline.fe.continuation import solve_path
from studies.convergence import at_points, probe_points, richardson, scaled_scene, study_scene
from fem_offline.geometry.meshing import mesh_for_scene
from fem_offline.fe.problem import build_problem
from fem_offline.scene import VOLUMETRIC, Scene

from contracts.cli import number
from studies import results
from studies.options import add_scales_flag, add_scene_flag, with_tolerances
from tqdm import tqdm

log = logging.getLogger("locking_check")
NOMINAL_NU = 0.495  # the scene's


def variant(scene: Scene, poisson: float, volumetric: str) -> Scene:
    """The scene with small-strain elasticity, every tissue's nu = `poisson` (E kept) and solver.volumetric."""
    tissues = {name: t.model_copy(update={"poisson": poisson, "youngs_kpa": t.youngs, "shear_wave_speed_m_s": None})
               for name, t in scene.tissues.items()}
    effects = scene.effects.model_copy(update={"geometric_nonlinearity": False})
    solver = scene.solver.model_copy(update={"volumetric": volumetric})
    return scene.model_copy(update={"tissues": tissues, "effects": effects, "solver": solver})


def edge_stats(mesh) -> dict:
    """Per tissue: tet count and median edge length (corner edges) in mm."""
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    corners = mesh.nodes[mesh.tets[:, :4]]
    edges = np.stack([np.linalg.norm(corners[:, a] - corners[:, b], axis=1) for a, b in pairs], axis=1)
    out = {}
    for i, name in enumerate(mesh.tissue_names):
        mask = mesh.tissue == i
        if mask.any():
            out[name] = {"tets": int(mask.sum()), "median_edge_mm": float(np.median(edges[mask]))}
    return out


def level_mesh(scene: Scene, scale: float, meshes: Path, out: Path):
    path = out / f"mesh_{scale:g}.npz"
    if not path.exists():
        study = meshes / f"mesh_{scale:g}.npz"
        if study.exists():
            shutil.copyfile(study, path)
        else:
            log.info("meshing sizes x %g", scale)
            write_mesh(path, mesh_for_scene(scaled_scene(scene, scale)))
    return read_mesh(path)


def solve_level(scene: Scene, scale: float, mesh, d_mm: float, beta: float) -> tuple[np.ndarray, float]:
    """Small strain is path-independent: one load step to d_mm (Newton iterates only on the contact)."""
    one_step = scene.solver.model_copy(update={"max_step_mm": d_mm})
    problem = build_problem(scaled_scene(scene, scale).model_copy(update={"solver": one_step}), mesh)
    t0 = time.perf_counter()
    *_, (_, u, _) = solve_path(problem, [d_mm], beta)
    return u, time.perf_counter() - t0


def analyse(rows: list[dict], scales: list[float]) -> dict:
    """Per nu: the GCI kind/order of each marker's |u| over every three consecutive levels."""
    out = {}
    for nu in sorted({r["poisson"] for r in rows}, reverse=True):
        by_scale = {r["scale"]: r for r in rows if r["poisson"] == nu}
        levels = [s for s in scales if s in by_scale]
        mags = np.array([np.linalg.norm(np.asarray(by_scale[s]["markers_mm"]), axis=1) for s in levels])
        triples = []
        for i in range(len(levels) - 2):
            s3, s2, s1 = levels[i:i + 3]
            ratio = (s3 / s2, s2 / s1)
            rs = [richardson(*mags[i:i + 3, m], ratio) for m in range(mags.shape[1])]
            triples.append({"scales": [s3, s2, s1], "kinds": [r.kind for r in rs],
                            "orders": [None if not np.isfinite(r.order) else round(float(r.order), 2) for r in rs]})
        changes = np.diff(mags, axis=0)  # level to the next finer one, per marker
        out[f"{nu:g}"] = {"scales": levels, "markers_abs_mm": mags.round(5).tolist(),
                          "change_max_mm": np.abs(changes).max(axis=1).round(5).tolist(),
                          "change_signed_mean_mm": changes.mean(axis=1).round(5).tolist(),
                          "relative_change_max": (np.abs(changes) / mags[1:]).max(axis=1).round(5).tolist(),
                          "triples": triples}
    return out


def result_name(volumetric: str, poisson: list[float]) -> str:
    """locking_check_VOLUMETRIC, with _nuNNN (0.45: _nu045) when the scene's nu 0.495 is not among --poisson."""
    suffix = "" if NOMINAL_NU in poisson else "".join(f"_nu{nu:g}".replace(".", "") for nu in poisson)
    return f"locking_check_{volumetric}" + suffix


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies locking-check", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_flag(ap)
    add_scales_flag(ap, [1.3, 1.0, 0.769, 0.5917, 0.455], "levels, coarsest first")
    ap.add_argument("--poisson", type=number("--poisson", minimum=0.0), nargs="+", default=[NOMINAL_NU, 0.45])
    ap.add_argument("--case", type=number("--case"), nargs=2, default=[2.0, 0.0], metavar=("D_MM", "BETA_DEG"))
    ap.add_argument("--volumetric", choices=VOLUMETRIC, default="pointwise",
                    help="the element's volumetric term (solver.volumetric): the P2 element as it is, per tet, "
                         "or a P1 pressure (Taylor-Hood)")
    ap.add_argument("--rtol", type=number("--rtol", minimum=0.0), default=1e-8)
    ap.add_argument("--contact-tol-mm", type=number("--contact-tol-mm", minimum=0.0), default=0.0005)
    ap.add_argument("--meshes", type=Path, default=Path("runs/convergence_resolve"),
                    help="the convergence study's folder: its level meshes are reused")
    ap.add_argument("--out", type=Path, default=Path("runs/locking"))
    ap.add_argument("--name",
                    help="the result's name (default: locking_check_VOLUMETRIC, _nuNNN for one nu other than 0.495)")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    if sorted(args.scales, reverse=True) != args.scales:
        ap.error("--scales: give them coarsest first (decreasing)")
    # tight tolerances: the level-to-level changes are hundredths of a mm, the default contact
    # tolerance (0.005 mm) would blur them
    base = with_tolerances(study_scene(args.scene, contact=True), args.rtol, args.contact_tol_mm)
    args.out.mkdir(parents=True, exist_ok=True)
    done_path = args.out / ("rows.json" if args.volumetric == "pointwise" else f"rows_{args.volumetric}.json")
    rows = json.loads(done_path.read_text()) if done_path.exists() else []
    d_mm, beta = args.case
    rows = [r for r in rows if r["case"] == [d_mm, beta]]
    meshes = {s: level_mesh(base, s, args.meshes, args.out) for s in args.scales}
    reference = meshes[min(args.scales, key=lambda s: abs(s - 1.0))]
    probes = probe_points(reference, base)
    for nu in args.poisson:
        scene = variant(base, nu, args.volumetric)
        for s in tqdm(args.scales, desc=f"nu {nu:g}", unit="level"):
            if any(r["poisson"] == nu and r["scale"] == s for r in rows):
                continue
            mesh = meshes[s]
            log.info("nu %g, sizes x %g (%d tets)", nu, s, len(mesh.tets))
            u, seconds = solve_level(scene, s, mesh, d_mm, beta)
            rows.append({"case": [d_mm, beta], "poisson": nu, "scale": s, "n_tets": len(mesh.tets),
                         "n_nodes": len(mesh.nodes), "seconds": round(seconds, 1),
                         "markers_mm": at_points(mesh, u, probes["markers"]).round(6).tolist(),
                         "interior_mm": at_points(mesh, u, probes["interior"]).round(6).tolist()})
            done_path.write_text(json.dumps(rows))
            log.info("  %.1f s, markers |u| %s", seconds,
                     np.linalg.norm(np.asarray(rows[-1]["markers_mm"]), axis=1).round(4))
    family = []
    for a, b in zip(args.scales, args.scales[1:] + [None]):
        entry = {"scale": a, "n_tets": len(meshes[a].tets), "tissues": edge_stats(meshes[a])}
        if b is not None:
            entry["tets_ratio_to_next"] = round(len(meshes[b].tets) / len(meshes[a].tets), 3)
            entry["nominal_ratio_cubed"] = round((a / b) ** 3, 3)
        family.append(entry)
    result = {
        "case": {"displacement_mm": d_mm, "angle_deg": beta, "physics": "small strain, tip in frictionless contact",
                 "volumetric": args.volumetric},
        "mesh_family": family, "by_poisson": analyse(rows, args.scales), "rows": rows}
    path = results.write(args.name or result_name(args.volumetric, args.poisson), result, publish=args.publish)
    for nu, r in result["by_poisson"].items():
        print(f"nu {nu}: marker max |change| to the next finer level {r['change_max_mm']} mm "
              f"(signed mean {r['change_signed_mean_mm']}); kinds {[sorted(set(t['kinds'])) for t in r['triples']]}")
    for f in family:
        print(f"sizes x {f['scale']:g}: {f['n_tets']:,} tets; ratio to next {f.get('tets_ratio_to_next')} "
              f"(r^3 {f.get('nominal_ratio_cubed')}); median edge "
              + ", ".join(f"{k} {v['median_edge_mm']:.2f}" for k, v in f["tissues"].items()))
    print(f"wrote {path}")
    return 0
