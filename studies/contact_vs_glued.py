"""The guide-wall model decided by measurement: glued patch vs rigid tip in contact (result contact_vs_glued).

    python -m studies contact-vs-glued [--scales 1.69 1.3 1] [--publish]

Reads the two grid-convergence studies' checkpoints (runs/convergence for the glued patch,
runs/convergence_contact for the tip in contact: `make convergence` and
`python -m studies convergence-study --guide contact --step-mm 0.5`; run those first, this command solves
nothing new once they are complete) on the same meshes, and reports for each hard case and level:
  * how far the two models are apart at the 8 markers, the prostate surface and the 3 interior points;
  * how much each model still changes from one level to the next (what refinement does to it);
  * min det F over the solver's quadrature points and over 11 points per tet, and the path's solve time.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from contracts.mesh import read_mesh
from studies import results
from studies.options import add_scales_flag, add_scene_flag
from studies.convergence import HARD_CASES, NEAR_TIP_MM, run_study, scaled_scene, study_scene
from fem_offline.fe.problem import build_problem
from fem_offline.fe.validity import resampled

MODELS = {"glued": (False, Path("runs/convergence")), "contact": (True, Path("runs/convergence_contact"))}


def _dist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a - b, axis=1)


def _stats(x: np.ndarray) -> dict:
    return {"max": float(x.max()), "mean": float(x.mean())}


def min_det_f(scene, scale: float, out: Path, case: tuple[float, float]) -> list[float]:
    """min det F at the case's checkpointed solution: over the solver's 4 quadrature points per tet,
    and over the 11 points of the degree-4 rule (the P2 field can invert between the solver's)."""
    d, beta = case
    mesh = read_mesh(out / f"mesh_{scale:g}.npz")
    with np.load(out / f"path_{scale:g}_{d:g}_{beta:g}.npz") as z:
        u = z["u"]
    problem = build_problem(scaled_scene(scene, scale), mesh)
    return [problem.min_jacobian(u), resampled(problem, 4).min_jacobian(u)]


def compare(scene_path: Path, scales: list[float]) -> dict:
    raws, scenes = {}, {}
    for name, (contact, out) in MODELS.items():
        # the glued study ran at the scene's 0.25 mm steps, the contact one at 0.5 mm (path-independent answers)
        scenes[name] = study_scene(scene_path, contact=contact, step_mm=0.5 if contact else None)
        raws[name] = run_study(scenes[name], scales, out)
    g, c = raws["glued"], raws["contact"]
    probes = g["probes"]
    near = np.linalg.norm(probes["prostate_surface"] - g["tip_mm"], axis=1) < NEAR_TIP_MM
    result = {"scales": scales, "n_tets": [lv["n_tets"] for lv in g["levels"]], "cases": {}}
    for d, beta in HARD_CASES:
        case = f"{d:g} mm, {beta:g} deg"
        rows = []
        for i, scale in enumerate(scales):
            ug, uc = g["levels"][i]["cases"][case], c["levels"][i]["cases"][case]
            row = {"scale": scale, "n_tets": g["levels"][i]["n_tets"],
                   "apart_mm": {"markers": _stats(_dist(ug["markers"], uc["markers"])),
                                "surface_near_tip": _stats(_dist(ug["prostate_surface"], uc["prostate_surface"])[near]),
                                "surface_rest": _stats(_dist(ug["prostate_surface"], uc["prostate_surface"])[~near]),
                                "interior": _dist(ug["interior"], uc["interior"]).tolist()},
                   "seconds": {"glued": ug["seconds"], "contact": uc["seconds"]},
                   "min_det_f": {n: min_det_f(scenes[n], scale, MODELS[n][1], (d, beta)) for n in MODELS}}
            if i:
                row["change_from_coarser_mm"] = {}
                for name, raw in raws.items():
                    a, b = raw["levels"][i - 1]["cases"][case], raw["levels"][i]["cases"][case]
                    surf = _dist(a["prostate_surface"], b["prostate_surface"])
                    row["change_from_coarser_mm"][name] = {
                        "markers_max": float(_dist(a["markers"], b["markers"]).max()),
                        "surface_near_tip_max": float(surf[near].max()), "surface_rest_max": float(surf[~near].max()),
                        "surface_mean": float(surf.mean()),
                        "interior_max": float(_dist(a["interior"], b["interior"]).max())}
            rows.append(row)
        result["cases"][case] = rows
    return result


def markdown(r: dict, command: str) -> str:
    lines = ["# Guide-wall model: glued patch vs rigid tip in contact", "",
             f"Written by `{command}`, from the checkpoints of the two grid-convergence studies "
             "(same meshes per level).",
             "Glued: the wall nodes within 6 mm of the tip follow it with the rounded-tip weight. Contact: a rigid "
             "sphere of radius 6 mm touching the wall at the tip, frictionless, augmented Lagrangian, "
             "penetration <= 0.005 mm.",
             f"Surface zones: prostate-surface points < {NEAR_TIP_MM:g} mm from the tip (near tip) and the rest. mm "
             "throughout.", ""]
    for case, rows in r["cases"].items():
        lines += [f"## {case}", "", "How much each model still changes when the mesh is refined (max over the points; "
                  "a model that converges changes less at each level):", "",
                  "| level (tets) | model | markers | surface near tip | surface rest | surface mean | interior |",
                  "|---|---|---|---|---|---|---|"]
        for row in rows[1:]:
            for name, ch in row["change_from_coarser_mm"].items():
                lines.append(f"| {row['n_tets']:,} | {name} | {ch['markers_max']:.3f} | "
                             f"{ch['surface_near_tip_max']:.3f} | {ch['surface_rest_max']:.3f} | "
                             f"{ch['surface_mean']:.3f} | {ch['interior_max']:.3f} |")
        lines += ["", "The two models apart, min det F and path solve time:", "",
                  "| level (tets) | markers max / mean | surface near tip max | surface rest max / mean | interior "
                  "(centroid, 5, 10 mm) | min det F glued / contact (4 points; 11 points) | time glued / contact |",
                  "|---|---|---|---|---|---|---|"]
        for row in rows:
            a = row["apart_mm"]
            lines.append(f"| {row['n_tets']:,} | {a['markers']['max']:.3f} / {a['markers']['mean']:.3f} | "
                         f"{a['surface_near_tip']['max']:.3f} | {a['surface_rest']['max']:.3f} / "
                         f"{a['surface_rest']['mean']:.3f} | "
                         + ", ".join(f"{x:.3f}" for x in a["interior"]) + " | "
                         f"{row['min_det_f']['glued'][0]:.3f} / {row['min_det_f']['contact'][0]:.3f}; "
                         f"{row['min_det_f']['glued'][1]:.3f} / {row['min_det_f']['contact'][1]:.3f} | "
                         f"{row['seconds']['glued'] / 60:.1f} / {row['seconds']['contact'] / 60:.1f} min |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies contact-vs-glued", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_flag(ap)
    add_scales_flag(ap, [1.69, 1.3, 1.0], "the studies' levels, coarsest first")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    result = compare(args.scene, args.scales)
    path = results.write("contact_vs_glued", {**result, "report_md": markdown(result, results.command())},
                         publish=args.publish)
    for case, rows in result["cases"].items():
        last = rows[-1]["change_from_coarser_mm"]
        print(f"{case}: last refinement changes markers by glued {last['glued']['markers_max']:.3f} / contact "
              f"{last['contact']['markers_max']:.3f} mm, surface near tip {last['glued']['surface_near_tip_max']:.3f} "
              f"/ {last['contact']['surface_near_tip_max']:.3f} mm; models apart at the markers "
              f"{rows[-1]['apart_mm']['markers']['max']:.3f} mm")
    print(f"wrote {path}")
    return 0
