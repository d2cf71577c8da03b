"""Hard cases: every corner and face centre of the patient stiffness box x beta, solved to the full push.

    python -m studies hard-cases [--elements mean_dilatation taylor_hood] [--workers 2] [--publish]

The box is a product of stiffness factors of the nominal E (prostate x0.4-1.6, adipose x0.5-1.6, rectal wall
x0.1-1.2, bladder x0.3-3 by default): its 16 corners and the centres of its 8 faces (one tissue at an end, the
others at the geometric centre of their ranges), each at beta = -10, 0 and 10 deg. Each is a load-stepped path from
rest to the scene's largest push (default.toml: 10 mm in 0.25 mm steps, halved on failure) on the served model's
mesh, once per element:

- "mean_dilatation": P2 displacement with a constant pressure and volume ratio per tet (the three-field u-p-J
  element of Simo, Taylor and Pister, condensed per element; fe/elasticity.py), and a contact penalty that scales
  with the rectal wall's E (guide.contact_stiffness_per_mm);
- "taylor_hood": P2 displacement with a continuous P1 pressure per tissue (fe/mixed.py), the fixed penalty.

Per solve it records whether it reached the full push, the largest push reached, load steps and halvings, Newton
iterations, the smallest det F at the quadrature points and the smallest tet volume ratio theta_e = v_e / V_e, with
the tissue and position where they occur, the contact penetration left and the seconds. Each solve is one JSON in
--out/<element>/ (resumable: a finished one is kept); --publish writes docs/results/hard_cases.json and its table.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from contracts.cli import number

from studies import results

log = logging.getLogger(__name__)

# The patient box as factors of the nominal E (issue: shear-wave elastography in patients; docs/materials.md).
BOX = {"prostate": (0.4, 1.6), "adipose": (0.5, 1.6), "rectal_wall": (0.1, 1.2), "bladder": (0.3, 3.0)}
# k / E_rectal_wall of the new formulation: default.toml's fixed 3e4 kPa/mm at the nominal wall (172.61 kPa)
CONTACT_PER_MM = 3e4 / 172.61
ELEMENTS = ("mean_dilatation", "taylor_hood")
SCENE = Path("fem_offline/scenes/default.toml")
MESH = Path("models/default/mesh.npz")


def box_points(box: dict[str, tuple[float, float]] = BOX) -> list[tuple[str, dict[str, float]]]:
    """(name, factor per tissue): the 2^m corners, then the 2m face centres (one tissue at an end, the others at
    the geometric centre of their ranges)."""
    names = list(box)
    centre = {t: float(np.sqrt(lo * hi)) for t, (lo, hi) in box.items()}
    points = []
    for ends in itertools.product((0, 1), repeat=len(names)):
        points.append(("corner " + "".join("-+"[e] for e in ends), {t: box[t][e] for t, e in zip(names, ends)}))
    for t in names:
        for e in (0, 1):
            points.append((f"face {t}{'-+'[e]}", {**centre, t: box[t][e]}))
    return points


def formulation(scene, element: str):
    """The scene with the element and its contact penalty: the new formulation scales the penalty with the wall."""
    guide = scene.guide.model_copy(update={"contact_stiffness_per_mm": CONTACT_PER_MM if element == "mean_dilatation"
                                           else None})
    return scene.model_copy(update={"solver": scene.solver.model_copy(update={"volumetric": element}), "guide": guide})


def at_factors(scene, factors: dict[str, float]):
    """The scene with each tissue's E multiplied by its factor."""
    tissues = dict(scene.tissues)
    for name, f in factors.items():
        tissues[name] = tissues[name].model_copy(update={"youngs_kpa": tissues[name].youngs * f,
                                                         "shear_wave_speed_m_s": None})
    return scene.model_copy(update={"tissues": tissues, "materials": None})


def worst_volume(problem, u: np.ndarray) -> dict:
    """Smallest det F at the quadrature points and smallest tet volume ratio, with the tissue and the tet centroid."""
    from fem_offline.fe import elasticity as el

    H = el.displacement_gradient(problem.G, problem.element_displacement(np.ravel(u)))
    J = np.linalg.det(H + np.eye(3))
    theta = el.tet_mean(problem.W, J)[0]
    tets = np.flatnonzero(problem.active) if problem.active is not None else np.arange(len(J))
    mesh = problem.mesh

    def where(e: int) -> dict:
        tet = tets[e]
        centroid = mesh.nodes[mesh.tets[tet, :4]].mean(axis=0)
        return {"tissue": mesh.tissue_names[mesh.tissue[tet]], "centroid_mm": np.round(centroid, 2).tolist()}

    e_j, e_t = int(np.argmin(J.min(axis=1))), int(np.argmin(theta))
    return {"min_det_f": float(J.min()), "min_det_f_at": where(e_j),
            "min_volume_ratio": float(theta.min()), "min_volume_ratio_at": where(e_t)}


def solve_one(scene_path: str, mesh_path: str | None, element: str, factors: dict[str, float], angle_deg: float,
              scale: float = 1.0) -> dict:
    """One path from rest to the scene's largest push: what it reached and what it cost."""
    from fem_offline.fe.continuation import solve_path
    from fem_offline.fe.newton import ConvergenceError
    from fem_offline.fe.problem import build_problem
    from fem_offline.geometry.meshing import load_or_build_mesh
    from fem_offline.scene import load_scene

    from studies.convergence import scaled_scene

    base = load_scene(scene_path)
    if scale != 1.0:
        base = scaled_scene(base, scale)
    scene = at_factors(formulation(base, element), factors)
    mesh = load_or_build_mesh(scene, mesh_path)
    problem = build_problem(scene, mesh)
    sweep = scene.sweep
    pushes = np.arange(1, round(sweep.displacement_max_mm / sweep.displacement_step_mm) + 1) * sweep.displacement_step_mm
    row = {"element": element, "factors": factors, "angle_deg": angle_deg, "n_tets": int(len(mesh.tets)),
           "target_mm": float(pushes[-1]), "reached_mm": 0.0, "load_steps": 0, "halvings": 0, "newton_iterations": 0,
           "factorizations": 0, "penetration_mm": 0.0, "failure": ""}
    t0, u = time.perf_counter(), np.zeros(problem.n_dofs)
    try:
        for d, u, stats in solve_path(problem, pushes, angle_deg):
            row.update(reached_mm=float(d), load_steps=row["load_steps"] + 1 + stats.halvings,
                       halvings=row["halvings"] + stats.halvings, penetration_mm=float(stats.penetration_mm),
                       newton_iterations=row["newton_iterations"] + stats.iterations,
                       factorizations=row["factorizations"] + stats.factorizations)
    except ConvergenceError as exc:
        row["failure"] = str(exc)
    row.update(solved=row["reached_mm"] >= row["target_mm"] - 1e-9, seconds=time.perf_counter() - t0,
               **worst_volume(problem, u))
    return row


def job_name(point: str, angle_deg: float) -> str:
    return f"{point.replace(' ', '_').replace('+', 'p').replace('-', 'm')}_b{angle_deg:+g}.json"


def run(out: Path, elements, angles, workers: int, scene: Path, mesh: Path | None,
        box: dict = BOX) -> list[dict]:
    """Solve every (element, point, beta) not yet in `out`; return every row found there."""
    from tqdm import tqdm

    todo = []
    for element in elements:
        (out / element).mkdir(parents=True, exist_ok=True)
        for (name, factors), angle in itertools.product(box_points(box), angles):
            path = out / element / job_name(name, angle)
            if not path.exists():
                todo.append((path, name, element, factors, angle))
    if todo:
        os.environ.setdefault("MKL_NUM_THREADS", "1" if workers > 1 else os.environ.get("MKL_NUM_THREADS", "2"))
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(solve_one, str(scene), str(mesh) if mesh else None, element, factors, angle):
                       (path, name) for path, name, element, factors, angle in todo}
            for f in tqdm(as_completed(futures), total=len(futures), desc="hard cases", unit="solve"):
                path, name = futures[f]
                row = {"point": name, **f.result()}
                path.write_text(json.dumps(row, indent=1) + "\n")
                log.info("%s %s beta %g: reached %.4g mm", row["element"], name, row["angle_deg"], row["reached_mm"])
    return collect(out, elements)


def collect(out: Path, elements) -> list[dict]:
    rows = []
    for element in elements:
        rows += [json.loads(p.read_text()) for p in sorted((out / element).glob("*.json"))]
    return rows


def markdown(rows: list[dict], box: dict, angles) -> str:
    """The side-by-side table: one line per point and beta, each element's outcome."""
    elements = list(dict.fromkeys(r["element"] for r in rows))
    by = {(r["element"], r["point"], r["angle_deg"]): r for r in rows}
    points = list(dict.fromkeys(r["point"] for r in rows))
    lines = ["# Hard cases", "",
             "The box: " + ", ".join(f"{t} x{lo:g} to x{hi:g}" for t, (lo, hi) in box.items())
             + " of the nominal E. A corner's signs give each tissue's end in that order; a face centre has one "
               "tissue at an end and the others at the geometric centre of their ranges.", ""]
    for element in elements:
        mine = [r for r in rows if r["element"] == element]
        solved = sum(r["solved"] for r in mine)
        lines.append(f"- **{element}**: {solved} of {len(mine)} solves reach the full push; smallest det F "
                     f"{min(r['min_det_f'] for r in mine):.3f}, smallest tet volume ratio "
                     f"{min(r['min_volume_ratio'] for r in mine):.3f}; {sum(r['seconds'] for r in mine) / 60:.0f} "
                     f"min in all, median {np.median([r['seconds'] for r in mine]):.0f} s a solve.")
    lines += ["", "| point | beta | " + " | ".join(f"{e}: reached (mm) | steps / halvings | Newton | min det F (tissue) "
                                                    f"| min theta_e | gap left (mm) | s" for e in elements) + " |",
              "|---|---|" + "---|---|---|---|---|---|---|" * len(elements)]
    for point in points:
        for angle in angles:
            cells = []
            for e in elements:
                r = by.get((e, point, angle))
                if r is None:
                    cells.append("not run | | | | | | ")
                    continue
                mark = f"**{r['reached_mm']:g}**" if r["solved"] else f"{r['reached_mm']:g} (failed)"
                cells.append(f"{mark} | {r['load_steps']} / {r['halvings']} | {r['newton_iterations']} | "
                             f"{r['min_det_f']:.3f} ({r['min_det_f_at']['tissue']}) | {r['min_volume_ratio']:.3f} | "
                             f"{r['penetration_mm']:.4f} | {r['seconds']:.0f}")
            lines.append(f"| {point} | {angle:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m studies hard-cases", description=__doc__.splitlines()[0])
    ap.add_argument("--elements", nargs="+", choices=ELEMENTS, default=list(ELEMENTS), help="elements, in this order")
    ap.add_argument("--angles", nargs="+", type=number("--angles"), default=[-10.0, 0.0, 10.0], help="beta (deg)")
    ap.add_argument("--workers", type=number("--workers", int, minimum=1), default=2, help="processes (default 2)")
    ap.add_argument("--scene", type=Path, default=SCENE)
    ap.add_argument("--mesh", type=Path, default=MESH, help="the mesh to solve on (default: models/default's)")
    ap.add_argument("--out", type=Path, default=Path("runs/hard_cases"), help="one JSON per solve (resumable)")
    ap.add_argument("--publish", action="store_true", help="write docs/results/hard_cases.json")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    rows = run(args.out, args.elements, args.angles, args.workers, args.scene, args.mesh)
    report = markdown(rows, BOX, args.angles)
    print(report)
    path = results.write("hard_cases", {"box": BOX, "contact_stiffness_per_mm": CONTACT_PER_MM, "rows": rows,
                                        "report_md": report}, publish=args.publish)
    print(f"\nwrote {path}")
    return 0
