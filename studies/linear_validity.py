"""Up to which guide displacement the linear model stays a deformation (result linear_validity).

    python -m studies linear-validity [--scene fem_offline/scenes/default.toml] [--sweep runs/default] [--publish]

On the scene's mesh (the nonlinear sweep's mesh.npz when --sweep is given, so both models are on
the same tets; otherwise the scene is meshed), computes the linear model's min det(I + grad u) and
its number of inverted tets at every (displacement, angle) of the scene's sweep grid, the exact
first crossing of det F = 0 per angle, and the tissue under the guide tip along its axis. With
--sweep it sets beside them the min det F the nonlinear snapshots recorded. The numbers come from
fem_offline/fe/validity.py; this command only lays them out (as JSON, with the Markdown report under
"report_md"). Takes seconds on the default mesh.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from contracts.cli import number
from contracts.mesh import read_mesh
from contracts.sweep import MESH_FILE, read_manifest
from fem_offline.geometry.meshing import mesh_for_scene
from fem_offline.fe.problem import build_problem
from fem_offline.scene import load_scene
from studies import results
from studies.options import SERVED_SCENE, add_scene_flag, json_ready
from fem_offline.fe.validity import (PROBE_INTORDER, bounded_min_det_f, det_f_curves, linear_bound_table,
                                     points_per_tet,
                                  probed_min_det_f, recorded_min_det_f, table_validity, tissue_along_axis, valid_up_to)


def _nonlinear(folder: Path, scene):
    manifest = read_manifest(folder)
    if manifest.scene_sha256 != scene.sha256():
        raise SystemExit(f"--sweep: {folder} is a sweep of another scene (sha256 {manifest.scene_sha256[:12]})")
    if not manifest.nonlinear:
        raise SystemExit(f"--sweep: {folder} is a linear sweep; give the nonlinear one to compare with")
    return manifest, read_mesh(folder / MESH_FILE)


def _summary(curves) -> dict:
    return {"valid_up_to_mm": valid_up_to(curves),
            "first_inversion_mm": min((c.first_inversion_mm for c in curves if c.first_inversion_mm is not None),
                                      default=None),
            "min_det_f_at_max": min(c.min_det_f[-1] for c in curves),
            "n_inverted_tets_at_max": [min(c.n_inverted_tets[-1] for c in curves),
                                       max(c.n_inverted_tets[-1] for c in curves)]}


def _table_summary(displacements_mm, table) -> dict:
    valid, first = table_validity(displacements_mm, table)
    return {"valid_up_to_mm": valid, "first_inverted_mm": first, "min_det_f": np.nanmin(table),
            "min_det_f_at_max": np.nanmin(table[:, -1]), "n_snapshots": int(np.isfinite(table).sum())}


def _as_the_sweep_records(displacements_mm, curves, dense, everywhere) -> dict:
    """What a linear sweep of this grid writes in its manifest's validity: a snapshot is inverted when det F
    is <= 0 at the solver's points, at the probe points or somewhere in a tet (its bound; fem_offline.sweep,
    contracts.sweep.validity_of)."""
    table = np.minimum.reduce([np.stack([c.min_det_f for c in curves]), np.stack([c.min_det_f for c in dense]),
                               everywhere])
    return {**_table_summary(displacements_mm, table), "n_inverted": int((table <= 0).sum())}


def study(scene_path: Path, sweep: Path | None, intorder: int) -> dict:
    scene = load_scene(scene_path)
    manifest, mesh = _nonlinear(sweep, scene) if sweep is not None else (None, mesh_for_scene(scene))
    problem = build_problem(load_scene(scene_path, effects={"geometric_nonlinearity": False, "guide_contact": False}),
                            mesh)
    grid = scene.sweep
    curves = det_f_curves(problem, grid.displacements_mm, grid.angles_deg)
    dense = det_f_curves(problem, grid.displacements_mm, grid.angles_deg, intorder=intorder)
    everywhere = linear_bound_table(problem, grid.displacements_mm, grid.angles_deg)
    out = {
        "scene": scene.name, "scene_sha256": scene.sha256(),
        "mesh": {"n_tets": len(mesh.tets), "n_nodes": len(mesh.nodes),
                 "source": str(sweep / MESH_FILE) if sweep is not None else "meshed from the scene"},
        "displacements_mm": grid.displacements_mm, "angles_deg": grid.angles_deg,
        "linear": _summary(curves),
        "tissue_along_axis_mm": [{"tissue": t, "from": a, "to": b} for t, a, b in tissue_along_axis(problem)],
        "angles": [{"angle_deg": c.angle_deg, "first_inversion_mm": c.first_inversion_mm,
                    "min_det_f_at_max": c.min_det_f[-1], "n_inverted_tets_at_max": c.n_inverted_tets[-1],
                    "inverted_tissues_at_max": c.inverted_at_max, "farthest_from_tip_mm": c.farthest_from_tip_mm,
                    "linear_min_det_f": c.min_det_f, "linear_n_inverted_tets": c.n_inverted_tets} for c in curves],
        "denser_points": {"intorder": intorder, "points_per_tet": points_per_tet(intorder),
                          "linear": _summary(dense)},
        "everywhere": {"linear": _table_summary(grid.displacements_mm, everywhere)},
        "linear_sweep_validity": _as_the_sweep_records(grid.displacements_mm, curves, dense, everywhere),
    }
    for row, c, b in zip(out["angles"], dense, everywhere):
        row["linear_min_det_f_denser"], row["linear_min_det_f_bound"] = c.min_det_f, b
    if manifest is not None:
        recorded = recorded_min_det_f(manifest)
        probed = probed_min_det_f(problem, sweep, manifest, intorder=intorder)
        out["nonlinear"] = {"sweep": str(sweep), **_table_summary(grid.displacements_mm, recorded)}
        t0 = time.perf_counter()
        bounded = bounded_min_det_f(problem, sweep, manifest)
        seconds = time.perf_counter() - t0
        out["denser_points"]["nonlinear"] = _table_summary(grid.displacements_mm, probed)
        out["everywhere"]["nonlinear"] = {**_table_summary(grid.displacements_mm, bounded), "seconds": seconds}
        for row, nl, nl_dense, nl_bound in zip(out["angles"], recorded, probed, bounded):
            row["nonlinear_min_det_f"], row["nonlinear_min_det_f_at_max"] = nl, nl[-1]
            row["nonlinear_min_det_f_denser"], row["nonlinear_min_det_f_bound"] = nl_dense, nl_bound
    return json_ready(out, digits=4)


def _span(first_mm) -> str:
    """Where the angles' first inverted displacements lie (None: not inverted), as words."""
    found = [d for d in first_mm if d is not None]
    if not found:
        return "nowhere"
    lo, hi = min(found), max(found)
    return f"at {lo:g} mm" if lo == hi else f"at {lo:g} to {hi:g} mm depending on the angle"


def _proved(summary: dict) -> str:
    """The nonlinear sweep's bound, as words."""
    if summary["min_det_f"] > 0:
        return f"det F >= {summary['min_det_f']:g} at every point of every tet in all {summary['n_snapshots']}, proved"
    return (f"inverted somewhere from {_span(summary['first_inverted_mm'])} (min {summary['min_det_f']:g}), "
            f"valid up to {summary['valid_up_to_mm']:g} mm")


def markdown(s: dict) -> str:
    d_max, step = s["displacements_mm"][-1], s["displacements_mm"][1] - s["displacements_mm"][0]
    lin, dp, nl = s["linear"], s["denser_points"], s.get("nonlinear")
    sw, ev = s["linear_sweep_validity"], s["everywhere"]
    wall = ", ".join(f"{r['tissue']} {r['from']:g}–{r['to']:g} mm" for r in s["tissue_along_axis_mm"])
    lines = [
        "# Up to which guide displacement the linear model is a deformation",
        "",
        f"Scene `{s['scene']}`, {s['mesh']['n_tets']:,} tets ({s['mesh']['source']}), the sweep's grid "
        f"({len(s['displacements_mm'])} displacements every {step:g} mm × {len(s['angles_deg'])} angles "
        f"{s['angles_deg'][0]:g}..{s['angles_deg'][-1]:g}°). ",
        "",
        "**The linear (small-strain) model with the glued guide patch (the superposable one; with the tip in contact "
        "the linear model is load-stepped, fem_offline/fe/contact.py) stays valid, det(I + ∇u) > 0 at every "
        f"quadrature point at every angle, up to {lin['valid_up_to_mm']:g} mm of guide push.** Its first element turns "
        f"inside out at {lin['first_inversion_mm']:g} mm (bisection on det F's cubic in d); at {d_max:g} mm min det F "
        f"is {lin['min_det_f_at_max']:g} with {lin['n_inverted_tets_at_max'][0]}–{lin['n_inverted_tets_at_max'][1]} "
        f"tets inverted, all within {max(r['farthest_from_tip_mm'] for r in s['angles']):g} mm of the guide tip "
        "(centroids). These are the points the solver integrates at (4 per tet).", "",
        f"Along the guide axis (β = 0) from the tip: {wall}.",
        "",
    ]
    if nl is not None:
        lines += [f"The nonlinear (neo-Hookean) sweep on the same mesh ({nl['sweep']}, {nl['n_snapshots']} snapshots) "
                  f"stays valid at those points everywhere: min det F {nl['min_det_f']:g} as its snapshots record it.",
                  ""]
    dense_nl = dp.get("nonlinear")
    lines += [f"**Between those points the P2 field inverts earlier.** At the {dp['points_per_tet']} points per tet of "
              f"the degree-{dp['intorder']} rule the linear model is valid up to {dp['linear']['valid_up_to_mm']:g} mm "
              f"(first inversion {dp['linear']['first_inversion_mm']:g} mm; min det F "
              f"{dp['linear']['min_det_f_at_max']:g} at {d_max:g} mm)"
              + (f", and the nonlinear snapshots up to {dense_nl['valid_up_to_mm']:g} mm (min det F "
                 f"{dense_nl['min_det_f_at_max']:g} at {d_max:g} mm): the solver keeps det F > 0 only where it "
                 f"integrates." if dense_nl else "."),
              "",
              f"**Everywhere in every tet it inverts earlier still.** On a straight-sided tet det F of a P2 field is a "
              f"cubic whose 20 Bernstein coefficients bound it from below; subdivided where they are not all > 0, they "
              f"prove det F > 0 at every point, or find a point (often a tet's corner, which no quadrature point "
              f"reaches) where it is <= 0 (`validity.det_f_bound`). So bounded, the linear model is valid up to "
              f"{ev['linear']['valid_up_to_mm']:g} mm (first inverted {_span(ev['linear']['first_inverted_mm'])}; "
              f"min det F {ev['linear']['min_det_f_at_max']:g} at {d_max:g} mm)"
              + (f". The nonlinear snapshots: {_proved(ev['nonlinear'])}." if ev.get("nonlinear") else "."),
              "",
              f"`fem_offline sweep` records min det F at both sets of points and its bound everywhere with every "
              "snapshot and counts a snapshot as inverted when any is <= 0: a linear sweep of this grid has "
              f"{sw['n_inverted']} of {sw['n_snapshots']} snapshots inverted, the first "
              f"{_span(sw['first_inverted_mm'])}, and is valid up to {sw['valid_up_to_mm']:g} mm at every angle; "
              f"`training fit` fits it only up to there and cuts the model's envelope there.", ""]
    head = ("| β (°) | first inversion (mm) | linear min det F at {0:g} mm | inverted tets at {0:g} mm | where "
            "| farthest from tip (mm) |")
    lines += [head.format(d_max) + (f" nonlinear min det F at {d_max:g} mm |" if nl else ""),
              "|---|---|---|---|---|---|" + ("---|" if nl else "")]
    for r in s["angles"]:
        where = ", ".join(f"{k} {v}" for k, v in r["inverted_tissues_at_max"].items()) or "–"
        first = "–" if r["first_inversion_mm"] is None else f"{r['first_inversion_mm']:g}"
        lines.append(f"| {r['angle_deg']:g} | {first} | {r['min_det_f_at_max']:g} | {r['n_inverted_tets_at_max']} | "
                     f"{where} | {r['farthest_from_tip_mm']:g} |"
                     + (f" {r['nonlinear_min_det_f_at_max']:g} |" if nl else ""))
    picks = s["angles"][::5]
    lines += ["", "min det F at the solver's points against displacement, every 1 mm (linear; nonlinear in brackets):",
              "", "| d (mm) | " + " | ".join(f"β = {r['angle_deg']:g}°" for r in picks) + " |",
              "|---|" + "---|" * len(picks)]
    for j, d in enumerate(s["displacements_mm"]):
        if abs(d - round(d)) < 1e-9:
            cells = [f"{r['linear_min_det_f'][j]:g}" + (f" ({r['nonlinear_min_det_f'][j]:g})" if nl else "")
                     for r in picks]
            lines.append(f"| {d:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies linear-validity", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_flag(ap, SERVED_SCENE, "the scene (default: the served model's)")
    ap.add_argument("--sweep", type=Path, help="the scene's nonlinear sweep folder (its mesh and recorded min det F)")
    results.add_publish_flag(ap)
    ap.add_argument("--intorder", type=number("--intorder", int, minimum=1), default=PROBE_INTORDER, help="a denser "
                    f"quadrature rule to probe det F between the solver's points (default {PROBE_INTORDER}, the "
                    "sweep's probe: 11 points per tet; the solver's rule has 4)")
    args = ap.parse_args(argv)
    s = study(args.scene, args.sweep, args.intorder)
    path = results.write("linear_validity", {**s, "report_md": markdown(s)}, publish=args.publish)
    lin, worst = s["linear"], min(s["angles"], key=lambda r: r["min_det_f_at_max"])
    line = (f"linear model valid up to {lin['valid_up_to_mm']:g} mm at every angle (first inversion "
            f"{lin['first_inversion_mm']:g} mm); at {s['displacements_mm'][-1]:g} mm min det F "
            f"{worst['min_det_f_at_max']:g} (beta {worst['angle_deg']:g} deg, "
            f"{worst['n_inverted_tets_at_max']} tets inverted)")
    if "nonlinear" in s:
        line += f"; nonlinear min det F {s['nonlinear']['min_det_f']:g} over {s['nonlinear']['n_snapshots']} snapshots"
    dp = s["denser_points"]
    line += (f". At {dp['points_per_tet']} points per tet: linear valid up to {dp['linear']['valid_up_to_mm']:g} mm"
             + (f", nonlinear up to {dp['nonlinear']['valid_up_to_mm']:g} mm" if "nonlinear" in dp else ""))
    ev = s["everywhere"]
    line += (f". Everywhere (bound): linear valid up to {ev['linear']['valid_up_to_mm']:g} mm"
             + (f", nonlinear {_proved(ev['nonlinear'])} ({ev['nonlinear']['seconds']:.1f} s for all, "
                f"{1e3 * ev['nonlinear']['seconds'] / ev['nonlinear']['n_snapshots']:.0f} ms per snapshot with its "
                f"file's reading)" if "nonlinear" in ev else ""))
    sw = s["linear_sweep_validity"]
    print(line)
    print(f"as a linear sweep records it (any of the three): {sw['n_inverted']} of {sw['n_snapshots']} snapshots "
          f"inverted, the first {_span(sw['first_inverted_mm'])}, valid up to {sw['valid_up_to_mm']:g} mm")
    print(f"wrote {path}")
