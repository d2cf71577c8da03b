"""A served model against the converged estimate of another element's grid-convergence study.

    python -m studies model-vs-converged --model models/default --study runs/convergence_contact_taylor_hood \
        --scales 1.3 1 0.769 0.5917 [--name fe_error_default] [--publish]

The grid-convergence study (`python -m studies convergence-study`, here with solver.volumetric = "taylor_hood")
keeps each level's mesh and each case's solution under --study. Per case, the three finest levels that solved it
(a case the finest level has not reached yet is judged on the three below), interpolated at
the model mesh's own nodes, give at every node the fine level's answer u1 and its GCI band (Roache,
one order per case from the mean |u|, studies.convergence.field_gci). The model's answer m at
the same case (ONNX, float32, the whole mesh) is then at most

    e(x) = |m(x) - u1(x)| + GCI(x)

from the converged estimate: measured end to end, surrogate and FE together. Its FE is within
e(x) + the surrogate's own error (triangle inequality; the surrogate error is the manifest's, held-out
cases), which is what `python -m training restamp` stamps as the FE discretisation error, so that the
stated end-to-end bound (surrogate + FE) is never below what was measured.

Per region of the model (markers, prostate surface, every node; the surface within 8 mm of the tip
apart) and per case (the hard cases the study solved) it writes the max of e, of |m - u1| and of the
band, and the max over the cases: the result fe_error_default (--name), in runs/results/ or, with
--publish, docs/results/, which `python -m training restamp --fe-error` reads.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from contracts.mesh import read_mesh
from contracts.model import onnx_session, read_model_folder
from studies import results
from studies.convergence import HARD_CASES, NEAR_TIP_MM, converged_estimate
from studies.options import add_cases_flag, add_study_flags


def compare(model: Path, study: Path, scales: list[float], cases) -> dict:
    folder = read_model_folder(model)
    manifest, mesh = folder.manifest, folder.mesh
    session = onnx_session(model / "model.onnx")
    tip = np.asarray(manifest.scene.spec.guide.tip_mm)
    surface = np.asarray(mesh.node_sets["prostate_surface"])
    near = np.linalg.norm(mesh.nodes[surface] - tip, axis=1) < NEAR_TIP_MM
    regions = {"markers": np.asarray(mesh.node_sets["markers"]), "prostate_surface": surface,
               "prostate_surface_near_tip": surface[near], "prostate_surface_rest": surface[~near],
               "all_nodes": np.arange(len(mesh.nodes))}
    out = {"cases": {}}
    for case in tqdm(cases, desc="cases", unit="case"):
        used, u1, band, order = converged_estimate(study, scales, case, mesh.nodes)
        m = session.run(None, {"guide": np.array([case], np.float32)})[0][0].astype(np.float64)
        gap = np.linalg.norm(m - u1, axis=1)
        e = gap + band
        out["cases"][f"{case[0]:g} mm, {case[1]:g} deg"] = {
            "scales": used, "mean_kind": order.kind,
            "mean_order": None if not np.isfinite(order.order) else float(order.order),
            "regions": {k: {"end_to_end_max_mm": float(e[ids].max()), "gap_max_mm": float(gap[ids].max()),
                            "band_max_mm": float(band[ids].max()), "end_to_end_mean_mm": float(e[ids].mean())}
                        for k, ids in regions.items()},
            "markers_model_mm": np.linalg.norm(m[regions["markers"]], axis=1).round(4).tolist(),
            "markers_fine_mm": np.linalg.norm(u1[regions["markers"]], axis=1).round(4).tolist()}
    out["max_over_cases"] = {k: max(c["regions"][k]["end_to_end_max_mm"] for c in out["cases"].values())
                             for k in regions}
    # the measured model's own surrogate error: the mesh's FE is within max_over_cases + this of the converged
    # estimate, for any later model on the mesh (training.fit.fe_through_model)
    out["model_surrogate_mm"] = {k: r.surrogate_mm for k, r in manifest.accuracy.regions.items()}
    return out


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies model-vs-converged", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=Path("models/default"))
    add_study_flags(ap)
    add_cases_flag(ap)
    ap.add_argument("--element", default="taylor_hood", help="the study's solver.volumetric, for the record")
    ap.add_argument("--name", default="fe_error_default", help="the result's name (default fe_error_default)")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    if len(args.scales) < 3:
        ap.error(f"--scales: need three levels at least, got {len(args.scales)}")
    cases = tuple(args.cases or HARD_CASES)
    try:
        result = compare(args.model, args.study, args.scales, cases)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    levels = []
    for s in sorted({s for row in result["cases"].values() for s in row["scales"]}, reverse=True):
        mesh = read_mesh(args.study / f"mesh_{s:g}.npz")
        levels.append({"scale": s, "n_tets": len(mesh.tets), "n_nodes": len(mesh.nodes)})
    model_mesh = read_model_folder(args.model).mesh
    result = {"kind": "model_vs_converged", "model": str(args.model), "element": args.element, "levels": levels,
              "model_mesh": {"n_tets": len(model_mesh.tets), "n_nodes": len(model_mesh.nodes)}, **result}
    path = results.write(args.name, result, publish=args.publish)
    for case, row in result["cases"].items():
        r = row["regions"]
        worst = ", ".join(f"{k.replace('_', ' ')} {v['end_to_end_max_mm']:.3f}" for k, v in r.items())
        levels_used = " x".join(f"{s:g}" for s in row["scales"])
        print(f"{case} (levels x{levels_used}), model vs converged ({args.element}), max |m - u_fine| + GCI in mm: "
              f"{worst}; at the markers a gap of {r['markers']['gap_max_mm']:.3f} + a band up to "
              f"{r['markers']['band_max_mm']:.3f}; mean |u| {row['mean_kind']}")
    print("max over the cases: " + ", ".join(f"{k} {v:.3f} mm" for k, v in result["max_over_cases"].items()))
    print(f"wrote {path}")
    return 0
