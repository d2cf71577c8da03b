"""Hard cases: every corner and face centre of the patient stiffness box x beta, solved to the full push.

    python -m studies hard-cases [--elements mean_dilatation taylor_hood] [--workers 2] [--publish]

The box is a product of stiffness factors of the nominal E, the scene's [materials] ranges over its tissues' E
(fem_offline/scenes/patient_box.toml: prostate x0.4-1.6, adipose x0.5-1.6, rectal wall x0.1-1.2, bladder x0.3-3): its 16
corners and the centres of its 8 faces (one tissue at an end, the others at the geometric centre of their ranges), each
at beta = 0 and 10 deg. The phantom is mirror-symmetric, so beta = -10 deg is the mirror image of +10
(tests/fem_offline/fe/test_contact.py::test_mirror_symmetry_with_contact): the same push reached, the same det F,
mirrored; --angles -10 0 10 solves it anyway. Each is a load-stepped path from rest to the scene's largest push
(default.toml: 10 mm in 0.25 mm steps, halved on failure) on the served model's mesh, once per element:

- "mean_dilatation", the scene's: P2 displacement with a constant pressure and volume ratio per tet (the three-field
  u-p-J element of Simo, Taylor and Pister, condensed per element; fe/elasticity.py), and a contact penalty that
  scales with the stiffest deforming tissue's E (guide.contact_stiffness_per_mm);
- "taylor_hood", models/default's: P2 displacement with a continuous P1 pressure per tissue (fe/mixed.py), the fixed
  penalty.

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

ELEMENTS = ("mean_dilatation", "taylor_hood")
SCENE = Path("fem_offline/scenes/patient_box.toml")
MESH = Path("models/default/mesh.npz")  # patient_box.toml meshes as default.toml does


ORDER = ("prostate", "adipose", "rectal_wall", "bladder")  # the order of a corner's signs, other tissues after


def box_of(scene) -> dict[str, tuple[float, float]]:
    """The scene's material ranges as factors of each tissue's nominal E (12 significant digits), in ORDER."""
    if not scene.materials:
        raise ValueError("--scene: the scene has no [materials]; there is no box to solve")
    names = sorted(scene.materials, key=lambda t: ORDER.index(t) if t in ORDER else len(ORDER))
    return {t: tuple(float(f"{e / scene.tissues[t].youngs:.12g}") for e in scene.materials[t].youngs_kpa_range)
            for t in names}


def box_points(box: dict[str, tuple[float, float]]) -> list[tuple[str, dict[str, float]]]:
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


def formulation(scene, element: str, contact_per_mm: float | None = None):
    """The scene with the element; Taylor-Hood with the fixed contact penalty (models/default's formulation), the
    other elements with k = contact_per_mm x the stiffest deforming tissue's E (default: the scene's
    guide.contact_stiffness_per_mm)."""
    per_mm = contact_per_mm if contact_per_mm is not None else scene.guide.contact_stiffness_per_mm
    guide = scene.guide.model_copy(update={"contact_stiffness_per_mm": None if element == "taylor_hood" else per_mm})
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
              scale: float = 1.0, probes: np.ndarray | None = None) -> dict:
    """One path from rest to the scene's largest push: what it reached and what it cost; with `probes` (k, 3), u
    interpolated there (mm) as "probes_mm"."""
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
    n_steps = round(sweep.displacement_max_mm / sweep.displacement_step_mm)
    pushes = np.arange(1, n_steps + 1) * sweep.displacement_step_mm
    row = {"element": element, "factors": factors, "angle_deg": angle_deg, "n_tets": int(len(mesh.tets)),
           "target_mm": float(pushes[-1]), "reached_mm": 0.0, "load_steps": 0, "halvings": 0, "newton_iterations": 0,
           "factorizations": 0, "penetration_mm": 0.0, "failure": ""}
    t0, u = time.perf_counter(), np.zeros(problem.n_dofs)
    try:
        for d, u, stats in solve_path(problem, pushes, angle_deg):  # noqa: B007 -- the last u is judged below
            row.update(reached_mm=float(d), load_steps=row["load_steps"] + 1 + stats.halvings,
                       halvings=row["halvings"] + stats.halvings, penetration_mm=float(stats.penetration_mm),
                       newton_iterations=row["newton_iterations"] + stats.iterations,
                       factorizations=row["factorizations"] + stats.factorizations)
    except ConvergenceError as exc:
        row["failure"] = str(exc)
    row.update(solved=row["reached_mm"] >= row["target_mm"] - 1e-9, seconds=time.perf_counter() - t0,
               **worst_volume(problem, u))
    if probes is not None:
        from studies.convergence import at_points

        row["probes_mm"] = at_points(mesh, np.reshape(u, (-1, 3)), probes).tolist()
    return row


def job_name(point: str, angle_deg: float) -> str:
    return f"{point.replace(' ', '_').replace('+', 'p').replace('-', 'm')}_b{angle_deg:+g}.json"


def run(out: Path, elements, angles, workers: int, scene: Path, mesh: Path | None, box: dict) -> list[dict]:
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


# The GCI's points: the nominal stiffnesses and the box's hardest corner (soft gland and fat, stiff wall and bladder)
GCI_POINTS = {"nominal": {"prostate": 1.0, "adipose": 1.0, "rectal_wall": 1.0, "bladder": 1.0},
              "hardest corner": {"prostate": 0.4, "adipose": 0.5, "rectal_wall": 1.2, "bladder": 3.0}}


def run_gci(out: Path, element: str, scales: list[float], workers: int, scene: Path, angle_deg: float = 0.0) -> dict:
    """Each GCI point at the full push on the scene meshed at every size x scale (coarsest first); the observed
    order, Richardson estimate and GCI (studies.convergence) of the smallest det F, the smallest tet volume ratio and
    the markers' displacement (at models/default's marker positions)."""
    from tqdm import tqdm

    from contracts.mesh import read_mesh

    from studies.convergence import field_gci, richardson

    markers = read_mesh(MESH)
    markers = markers.nodes[markers.node_sets["markers"]]
    folder = out / "gci" / element
    folder.mkdir(parents=True, exist_ok=True)
    todo = [(name, s) for name in GCI_POINTS
            for s in scales if not (folder / f"{name.replace(' ', '_')}_x{s:g}.json").exists()]
    if todo:
        os.environ.setdefault("MKL_NUM_THREADS", "1" if workers > 1 else os.environ.get("MKL_NUM_THREADS", "2"))
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(solve_one, str(scene), None, element, GCI_POINTS[name], angle_deg, s, markers):
                       (name, s) for name, s in todo}
            for f in tqdm(as_completed(futures), total=len(futures), desc="GCI", unit="solve"):
                name, s = futures[f]
                (folder / f"{name.replace(' ', '_')}_x{s:g}.json").write_text(json.dumps(f.result(), indent=1) + "\n")
    report = {}
    for name in GCI_POINTS:
        rows = [json.loads((folder / f"{name.replace(' ', '_')}_x{s:g}.json").read_text()) for s in scales]
        if len(rows) < 3 or not all(r["solved"] for r in rows):
            report[name] = {"levels": rows, "analysis": "a level did not solve; no GCI"}
            continue
        ratio = (scales[0] / scales[1], scales[1] / scales[2])
        one = {}
        for key in ("min_det_f", "min_volume_ratio"):
            r = richardson(*(x[key] for x in rows[-3:]), ratio)
            one[key] = {"values": list(r.values), "kind": r.kind, "order": r.order, "extrapolated": r.extrapolated,
                        "gci_fine": r.gci_fine}
        band, mean = field_gci(*(np.array(x["probes_mm"]) for x in rows[-3:]), ratio)
        one["markers_mm"] = {"gci_fine_max_mm": float(band.max()), "kind": mean.kind, "order": mean.order,
                             "fine_max_abs_mm": float(np.linalg.norm(rows[-1]["probes_mm"], axis=1).max())}
        report[name] = {"levels": [{k: x[k] for k in ("n_tets", "seconds", "min_det_f", "min_volume_ratio",
                                                       "min_det_f_at", "reached_mm", "newton_iterations")}
                                   for x in rows],
                        "scales": scales, **one}
    return report


def run_cost(out: Path, elements, workers: int, scene: Path, mesh: Path | None) -> dict:
    """Each element's solve of the nominal stiffnesses at 10 mm, beta 0 on the model's mesh: seconds and work."""
    folder = out / "cost"
    folder.mkdir(parents=True, exist_ok=True)
    todo = [e for e in elements if not (folder / f"{e}.json").exists()]
    if todo:
        os.environ.setdefault("MKL_NUM_THREADS", "1" if workers > 1 else os.environ.get("MKL_NUM_THREADS", "2"))
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(solve_one, str(scene), str(mesh) if mesh else None, e, GCI_POINTS["nominal"], 0.0): e
                       for e in todo}
            for f in as_completed(futures):
                (folder / f"{futures[f]}.json").write_text(json.dumps(f.result(), indent=1) + "\n")
    return {e: json.loads((folder / f"{e}.json").read_text()) for e in elements}


def cost_markdown(cost: dict) -> str:
    lines = ["## The element's cost (nominal stiffnesses, 10 mm, beta 0, the model's mesh; solved side by side)", "",
             "| element | seconds | load steps | Newton iterations | factorisations | min det F | min theta_e |",
             "|---|---|---|---|---|---|---|"]
    for e, r in cost.items():
        lines.append(f"| {e} | {r['seconds']:.0f} | {r['load_steps']} | {r['newton_iterations']} | "
                     f"{r['factorizations']} | {r['min_det_f']:.3f} | {r['min_volume_ratio']:.3f} |")
    return "\n".join(lines)


def _or_dash(x: float, spec: str) -> str:
    """x formatted, or a dash where it is not a number (no order unless the levels converge monotonically)."""
    return "—" if not np.isfinite(x) else format(x, spec)


def gci_markdown(gci: dict, element: str) -> str:
    lines = [f"## Grid convergence of the worst element ({element}, 10 mm, beta 0)", "",
             "| point | tets | min det F | min theta_e | seconds |", "|---|---|---|---|---|"]
    for name, g in gci.items():
        for lv in g["levels"]:
            lines.append(f"| {name} | {lv['n_tets']:,} | {lv['min_det_f']:.4f} | {lv['min_volume_ratio']:.4f} | "
                         f"{lv['seconds']:.0f} |")
    lines += ["", "| point | quantity | kind | order | extrapolated | GCI (fine) |", "|---|---|---|---|---|---|"]
    for name, g in gci.items():
        if isinstance(g.get("analysis"), str):
            lines.append(f"| {name} | {g['analysis']} | | | | |")
            continue
        for key in ("min_det_f", "min_volume_ratio"):
            q = g[key]
            lines.append(f"| {name} | {key} | {q['kind']} | {_or_dash(q['order'], '.2f')} | "
                         f"{_or_dash(q['extrapolated'], '.4f')} | {q['gci_fine']:.4f} |")
        m = g["markers_mm"]
        lines.append(f"| {name} | markers' displacement (mm) | {m['kind']} | {_or_dash(m['order'], '.2f')} | "
                     f"largest on the fine mesh {m['fine_max_abs_mm']:.3f} mm | {m['gci_fine_max_mm']:.4f} mm |")
    return "\n".join(lines)


FAT_BANDS_MM = (0.0, 4.0, 6.0, 8.0, 10.0, 14.0)  # distance from the guide's axis


def fat_between_wall_and_gland(mesh, guide, *, reach_mm: float = 14.0, spacing_mm: float = 1.0,
                               sample_mm: float = 0.01) -> dict:
    """The fat between the rectal wall and the prostate in front of the tip: along lines parallel to the guide's axis
    on a grid around it (spacing_mm, out to reach_mm), each run of adipose that has rectal wall before it and prostate
    after it: its thickness (mm) and the distinct tets it crosses, summarised per band of distance from the axis."""
    from contracts.interpolate import PointLocator

    tip, axis = np.asarray(guide.tip_mm, float), np.asarray(guide.axis, float)
    a = np.cross(axis, guide.tilt_normal)
    a /= np.linalg.norm(a)
    b = np.cross(axis, a)
    locator = PointLocator(mesh.nodes, mesh.tets[:, :4])
    s = np.arange(-8.0, 30.0, sample_mm)
    runs = []  # (distance from the axis, tets crossed, thickness)
    grid = np.arange(-reach_mm, reach_mm + 1e-9, spacing_mm)
    for x, y in itertools.product(grid, grid):
        if np.hypot(x, y) > reach_mm:
            continue
        tet, _ = locator.locate(tip + x * a + y * b + s[:, None] * axis)
        tissue = np.where(tet >= 0, mesh.tissue[np.maximum(tet, 0)], -1)
        edges = np.flatnonzero(np.diff(tissue)) + 1
        starts, ends = np.r_[0, edges], np.r_[edges, len(s)]
        names = [mesh.tissue_names[t] if t >= 0 else "" for t in tissue[starts]]
        for k in range(1, len(starts) - 1):
            if names[k - 1:k + 2] == ["rectal_wall", "adipose", "prostate"]:
                runs.append((float(np.hypot(x, y)), len(set(tet[starts[k]:ends[k]])),
                             float(s[ends[k] - 1] - s[starts[k]] + sample_mm)))
    bands = []
    for lo, hi in zip(FAT_BANDS_MM[:-1], FAT_BANDS_MM[1:]):
        mine = [r for r in runs if lo <= r[0] < hi]
        row = {"from_axis_mm": [lo, hi], "lines": len(mine)}
        if mine:
            count, thick = np.array([r[1] for r in mine]), np.array([r[2] for r in mine])
            row.update(tets_min=int(count.min()), tets_median=float(np.median(count)), tets_max=int(count.max()),
                       thickness_min_mm=float(thick.min()), thickness_median_mm=float(np.median(thick)),
                       thickness_max_mm=float(thick.max()))
        bands.append(row)
    return {"spacing_mm": spacing_mm, "bands": bands}


def fat_markdown(fat: dict) -> str:
    lines = ["## The fat between the rectal wall and the gland, in front of the tip (the served mesh)", "",
             f"Lines parallel to the guide's axis on a {fat['spacing_mm']:g} mm grid around it; on each, the run of "
             "adipose with rectal wall before it and prostate after it.", "",
             "| from the axis | lines through fat | tets across: min / median / max | thickness: min / median / max |",
             "|---|---|---|---|"]
    for b in fat["bands"]:
        lo, hi = b["from_axis_mm"]
        if not b["lines"]:
            lines.append(f"| {lo:g}-{hi:g} mm | 0 (the gland lies on the wall) | | |")
            continue
        lines.append(f"| {lo:g}-{hi:g} mm | {b['lines']} | {b['tets_min']} / {b['tets_median']:g} / {b['tets_max']} | "
                     f"{b['thickness_min_mm']:.2f} / {b['thickness_median_mm']:.2f} / {b['thickness_max_mm']:.2f} mm |")
    return "\n".join(lines)


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
    total = len(box_points(box)) * len(angles)
    for element in elements:
        mine = [r for r in rows if r["element"] == element]
        solved = sum(r["solved"] for r in mine)
        lines.append(f"- **{element}**: {len(mine)} of the {total} solves run; {solved} of {len(mine)} reach the full "
                     f"push; smallest det F {min(r['min_det_f'] for r in mine):.3f}, smallest tet volume ratio "
                     f"{min(r['min_volume_ratio'] for r in mine):.3f}; {sum(r['seconds'] for r in mine) / 60:.0f} "
                     f"min in all, median {np.median([r['seconds'] for r in mine]):.0f} s a solve.")
    lines += ["", "| point | beta | " + " | ".join(f"{e}: reached (mm) | steps / halvings | Newton | min det F "
                                                    f"(tissue) | min theta_e | gap left (mm) | s" for e in elements)
              + " |", "|---|---|" + "---|---|---|---|---|---|---|" * len(elements)]
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
    ap.add_argument("--angles", nargs="+", type=number("--angles"), default=[0.0, 10.0],
                    help="beta (deg; default 0 10: -10 mirrors 10 on the symmetric phantom)")
    ap.add_argument("--workers", type=number("--workers", int, minimum=1), default=2, help="processes (default 2)")
    ap.add_argument("--scene", type=Path, default=SCENE)
    ap.add_argument("--mesh", type=Path, default=MESH, help="the mesh to solve on (default: models/default's)")
    ap.add_argument("--out", type=Path, default=Path("runs/hard_cases"), help="one JSON per solve (resumable)")
    ap.add_argument("--gci", nargs=3, type=number("--gci"), metavar="SCALE",
                    help="also the GCI of the nominal point and the hardest corner on the scene meshed at these size "
                         "multipliers, coarsest first (e.g. 1.3 1 0.769), with the first element")
    ap.add_argument("--cost", action="store_true", help="also each element's solve at the nominal stiffnesses")
    ap.add_argument("--cases", action=argparse.BooleanOptionalAction, default=True,
                    help="solve the box's points (--no-cases: only --cost and --gci)")
    ap.add_argument("--no-solve", action="store_true", help="publish the solves already in --out; start none")
    ap.add_argument("--publish", action="store_true", help="write docs/results/hard_cases.json")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    from fem_offline.scene import load_scene

    base = load_scene(args.scene)
    box = box_of(base)
    if args.no_solve or not args.cases:
        rows = collect(args.out, args.elements)
    else:
        rows = run(args.out, args.elements, args.angles, args.workers, args.scene, args.mesh, box)
    rows = [r for r in rows if r["angle_deg"] in args.angles]
    report = markdown(rows, box, args.angles)
    data = {"scene": str(args.scene), "box": box, "contact_stiffness_per_mm": base.guide.contact_stiffness_per_mm,
            "rows": rows}
    if args.cost and not args.no_solve:
        data["cost"] = run_cost(args.out, args.elements, args.workers, args.scene, args.mesh)
    elif (args.out / "cost").exists():
        data["cost"] = {p.stem: json.loads(p.read_text()) for p in sorted((args.out / "cost").glob("*.json"))}
    if data.get("cost"):
        report += "\n\n" + cost_markdown(data["cost"])
    from contracts.mesh import read_mesh

    data["fat"] = fat_between_wall_and_gland(read_mesh(args.mesh), base.guide)
    report += "\n\n" + fat_markdown(data["fat"])
    if args.gci:
        data["gci"] = run_gci(args.out, args.elements[0], list(args.gci), args.workers, args.scene)
        report += "\n\n" + gci_markdown(data["gci"], args.elements[0])
    print(report)
    path = results.write("hard_cases", {**data, "report_md": report}, publish=args.publish)
    print(f"\nwrote {path}")
    return 0
