"""Grid-convergence study of the nonlinear FE at the prostate (Roache's GCI): result convergence_<guide or element>.

    python -m studies convergence-study --guide contact --step-mm 0.5 [--scales 1.69 1.3 1]   # -> convergence_pointwise
    python -m studies convergence-study --guide glued                   # -> convergence_glued, runs/convergence
    python -m studies convergence-study --volumetric taylor_hood --publish   # -> docs/results/convergence_taylor_hood.json

The result (the levels, the probe points, the analysis) goes to runs/results/NAME.json, with
--publish to docs/results/NAME.json, its plot beside it as NAME.png; the field data (meshes and
path checkpoints) and a Markdown report (report.md) to --out. NAME (--name) defaults to
convergence_glued for the glued patch, convergence_pointwise for the tip in contact with the P2
element, else convergence_<volumetric>.

Meshes the scene with every size multiplied by each scale (a constant ratio between levels),
solves the hard cases on each, resumably (every converged load step is checkpointed under --out;
rerun the same command to resume), and reports for the three finest levels the observed order,
the Richardson estimate, the GCI and the monotonic/oscillatory kind of each quantity
(studies/convergence.py). Set MKL_NUM_THREADS (2 on this machine) for PARDISO.
"""  # noqa: E501 -- argparse prints this docstring as it is (--help)

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np

from fem_offline.scene import VOLUMETRIC
from studies import results
from studies.convergence import HARD_CASES, NEAR_TIP_MM, analyse, run_study, study_scene
from studies.options import add_cases_flag, add_scales_flag, add_scene_flag, json_ready
from contracts.cli import number


BIG = ("prostate_surface", "nodes")  # fields at thousands of points: summarised, not stored


def _fmt(r: dict) -> str:
    p = "—" if r["order"] is None else f"{r['order']:.2f}"  # NaN is null in the JSON
    ext = "—" if r["extrapolated_mm"] is None else f"{r['extrapolated_mm']:.3f}"
    v = r["values_mm"]
    return f"{v[0]:.3f} / {v[1]:.3f} / {v[2]:.3f} | {r['kind']} | {p} | {ext} | {r['gci_fine_mm']:.3f}"


def markdown(result: dict, command: str, seconds: float, image: str = "convergence.png") -> str:
    lv, below = result["levels"], result.get("coarser_levels", [])
    keys = [f"{x['scale']:g}" for x in below]

    def more(r: dict, summary: bool = False) -> str:  # the bounds of the levels coarser than the three
        b = r.get("bound_by_scale_mm", {})
        return "".join(f" max {b[k]['max']:.3f}, p95 {b[k]['p95']:.3f} |" if summary else f" {b[k]:.3f} |"
                       for k in keys)

    lines = ["# Grid convergence at the prostate", "",
             f"Written by `{command}` ({seconds / 60:.0f} min of solving, summed over the levels).", "",
             "Levels (every mesh size scaled together, ratios r32 = {:.4f}, r21 = {:.4f}): ".format(*result["ratios"])
             + ", ".join(f"{x['n_tets']:,} tets (sizes x {x['scale']:g})" for x in [*below, *lv]) + "."
             + (" The GCI comes from the three finest." if below else ""),
             "Values are |u| in mm, coarse / medium / fine; p is the observed order (Celik's fixed point where "
             "r32 != r21); the estimate is Richardson's; GCI is the fine mesh's error band (Fs = 1.25), in mm. "
             "\"GCI vector\" is the band of the displacement vector at that point: Fs |u_fine - u_medium| / (r21^q - "
             "1) with one order per case, that of the mean |u| over every node (its kind is on the \"every node\" "
             "row); where that mean does not converge monotonically, Fs times the larger change between levels. "
             "\"Medium bound\" is how far the medium mesh can be from the converged value: |u_medium - u_fine| + "
             "the fine GCI vector, point by point; \"coarse bound\" the same for the coarse mesh"
             + "".join(f"; \"bound x{x['scale']:g}\" the same for the level under the three, {x['n_tets']:,} tets "
                       f"(sizes x {x['scale']:g})" for x in below) + ".", ""]
    head = ("| quantity | coarse / medium / fine | kind | p | Richardson | GCI fine | GCI vector | medium bound | "
            "coarse bound |" + "".join(f" bound x{k} |" for k in keys)
            + "\n|---|---|---|---|---|---|---|---|---|" + "---|" * len(keys))
    for case, row in result["cases"].items():
        times = ", ".join(f"{s / 60:.1f} min" for s in row["seconds"])
        lines += [f"## {case}", "", "Solve time per level, coarsest first: " + times, "", head]
        for i, r in enumerate(row["markers"]):
            lines.append(f"| marker {i + 1} | {_fmt(r)} | {r['gci_vector_mm']:.3f} | {r['bound_medium_mm']:.3f} | "
                         f"{r['bound_coarse_mm']:.3f} |" + more(r))
        for name, r in zip(("prostate centroid", "5 mm in front of the tip", "10 mm in front of the tip"),
                           row["interior"]):
            lines.append(f"| {name} | {_fmt(r)} | {r['gci_vector_mm']:.3f} | {r['bound_medium_mm']:.3f} | "
                         f"{r['bound_coarse_mm']:.3f} |" + more(r))
        for zone in ("near_tip", "rest"):
            z = row[f"surface_{zone}"]
            label = f"surface < {NEAR_TIP_MM:g} mm from the tip" if zone == "near_tip" else "surface, the rest"
            for stat in ("max", "p95", "mean"):
                lines.append(f"| {label}: {stat} | {_fmt(z[stat])} | | | |" + " |" * len(keys))
            g, b, c = z["gci_mm"], z["bound_medium_mm"], z["bound_coarse_mm"]
            lines.append(f"| {label}: pointwise band ({z['n_points']} points) | max {g['max']:.3f}, p95 "
                         f"{g['p95']:.3f}, mean {g['mean']:.3f} | | | | | | max {b['max']:.3f}, p95 {b['p95']:.3f} | "
                         f"max {c['max']:.3f}, p95 {c['p95']:.3f} |" + more(z, summary=True))
        a = row["all_nodes"]
        g, b, c = a["gci_mm"], a["bound_medium_mm"], a["bound_coarse_mm"]
        lines.append(f"| every node: pointwise band ({a['n_points']} points) | max {g['max']:.3f}, "
                     f"p95 {g['p95']:.3f}, mean {g['mean']:.3f} | {a['mean_kind']} | | | | | "
                     f"max {b['max']:.3f}, p95 {b['p95']:.3f} | max {c['max']:.3f}, p95 {c['p95']:.3f} |"
                     + more(a, summary=True))
        lines.append("")
    lines += [f"![convergence]({image})", ""]
    return "\n".join(lines)


def plot(raw: dict, result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(result["cases"]), figsize=(5 * len(result["cases"]), 4), squeeze=False)
    h = [lv["scale"] for lv in raw["levels"]]
    for ax, case in zip(axes[0], result["cases"]):
        for group, marker in (("markers", "o"), ("interior", "s")):
            mags = np.array([np.linalg.norm(lv["cases"][case][group], axis=1) for lv in raw["levels"]])  # (levels, k)
            for k in range(mags.shape[1]):
                ax.plot(h, mags[:, k], marker=marker, lw=0.8, label=group if k == 0 else None)
        ax.set(xlabel="mesh size / default", ylabel="|u| (mm)", title=case)
        ax.invert_xaxis()
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def names(scene) -> tuple[str, str]:
    """(the result's name, the field data's folder under runs/) of a study of `scene`."""
    contact, element = scene.effects.guide_contact, scene.solver.volumetric
    folder = ("convergence_contact" if contact else "convergence") + ("" if element == "pointwise" else f"_{element}")
    if element != "pointwise":
        return f"convergence_{element}", folder
    return ("convergence_pointwise" if contact else "convergence_glued"), folder


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m studies convergence-study", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_flag(ap)
    add_scales_flag(ap, [1.69, 1.3, 1.0], "size multipliers, coarsest first")
    ap.add_argument("--guide", choices=("contact", "glued"),
                    help="the guide-wall model: the rigid tip in frictionless contact, or the glued patch (default: "
                         "the scene's)")
    ap.add_argument("--step-mm", type=number("--step-mm", minimum=1e-3),
                    help="load step along each path (default: the scene's solver.max_step_mm)")
    ap.add_argument("--volumetric", choices=VOLUMETRIC,
                    help="the element's volumetric term (solver.volumetric; default: the scene's)")
    ap.add_argument("--out", type=Path, help="meshes, checkpoints and report.md, resumable "
                    "(default runs/convergence[_contact][_VOLUMETRIC])")
    ap.add_argument("--name", help="the result's name (default: convergence_glued, convergence_pointwise or "
                    "convergence_VOLUMETRIC, from the guide and the element)")
    add_cases_flag(ap)
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    t0 = time.perf_counter()
    scene = study_scene(args.scene, contact=None if args.guide is None else args.guide == "contact",
                        step_mm=args.step_mm, volumetric=args.volumetric)
    name, folder = names(scene)
    name, out = args.name or name, args.out or Path("runs") / folder
    raw = run_study(scene, args.scales, out, tuple(args.cases or HARD_CASES))
    result = analyse(raw)
    seconds = sum(sum(lv["cases"][c]["seconds"] for c in lv["cases"]) for lv in raw["levels"])
    small = {"levels": [{k: lv[k] for k in ("scale", "n_tets", "n_nodes")} | {"cases": {
        c: {k: v for k, v in lv["cases"][c].items() if k not in BIG} for c in lv["cases"]}} for lv in raw["levels"]],
        "probes": {k: v for k, v in raw["probes"].items() if k not in BIG}, "analysis": result}
    path = results.write(name, json_ready(small), publish=args.publish)
    plot(raw, result, path.with_suffix(".png"))
    (out / "report.md").write_text(markdown(json_ready(result), results.command(), seconds,
                                            image=str(path.with_suffix(".png"))))
    print_bounds(result)
    print(f"wrote {path}, {path.with_suffix('.png')} and {out / 'report.md'} "
          f"({time.perf_counter() - t0:.0f} s this run)")
    return 0


def print_bounds(result: dict) -> None:
    """Per case and level, the largest bound at the markers, the interior points and the prostate surface."""
    for case, row in result["cases"].items():
        def bound(r: dict, key: str):
            return r[key] if key in r else r["bound_by_scale_mm"][key]

        levels = [("fine", "gci_vector_mm", "gci_mm"), ("medium", "bound_medium_mm", "bound_medium_mm"),
                  ("coarse", "bound_coarse_mm", "bound_coarse_mm")]
        levels += [(f"x{lv['scale']:g}", f"{lv['scale']:g}", f"{lv['scale']:g}") for lv in result["coarser_levels"]]
        for level, point, field in levels:
            m = max(bound(r, point) for r in row["markers"])
            i = max(bound(r, point) for r in row["interior"])
            near, rest = (bound(row[f"surface_{z}"], field) for z in ("near_tip", "rest"))
            print(f"{case}, {level} level: markers max {m:.3f} mm, interior max {i:.3f} mm; prostate surface near tip "
                  f"max {near['max']:.3f} mm, rest max {rest['max']:.3f} mm, mean {rest['mean']:.3f} mm")
