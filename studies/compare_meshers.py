"""Label-map meshers on the voxelised phantom: tets, time, validity, quality, tissue volumes, conformity, linear FE.

    python -m studies compare-meshers --spacing-mm 1 0.5 [--scene fem_offline/scenes/grid_study_base.toml] \
        [--meshers cgal tetgen] [--ftetwild] [--publish]

Each label map is the phantom voxelised as `python -m studies make-labelmap` does (written under --work);
volumes are against the exact phantom (voxel centres at 0.25 mm), markers against the gmsh phantom
mesh's linear answer at its 8 markers (10 mm, beta = 0, guide glued), next to how much that answer
moves when the gmsh mesh is refined by 1.3. A mesher whose package is missing is skipped. The result
is meshers, with the scene's file name for another scene than the studies' base (meshers_tiny) and
the meshers for another set than cgal and tetgen (meshers_ftetwild); --name overrides it.
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import sys
from pathlib import Path

from studies.meshers import study
from contracts.cli import number
from fem_offline.scene import load_scene
from studies import results
from studies.options import GRID_STUDY_SCENE, SERVED_SCENE, add_scene_flag

PACKAGE = {"cgal": "pygalmesh", "tetgen": "tetgen", "ftetwild": "pytetwild"}
DEFAULT_MESHERS = ["cgal", "tetgen"]
TISSUES = ("prostate", "rectal_wall", "bladder", "pubic_bone", "spine", "adipose")


def table(result: dict) -> str:
    head = ("| voxel | mesher | tets | time | inverted | degenerate | min dihedral | "
            + " | ".join(t.replace("_", " ") for t in TISSUES)
            + " | 3-owner faces | prostate surface to voxels, max / mean | linear solve | max marker diff |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in result["rows"]:
        vol = " | ".join(f"{100 * r['volume_error'][t]:+.1f} %" for t in TISSUES)
        diff = f"{r['marker_difference_max_mm']:.3f} mm" if "marker_difference_max_mm" in r else "-"
        solve = r["linear_solve"].split(":")[0]  # runs, fails, not run
        d = r["prostate_surface_to_voxels"]
        lines.append(f"| {r['spacing_mm']:g} mm | {r['mesher']} | {r['tets']:,} | {r['seconds']:.1f} s | "
                     f"{r['inverted']} | {r['degenerate']} | {r['min_dihedral_deg']:.1f}° | {vol} | "
                     f"{r['faces_with_three_owners']} | {d['max_mm']:.2f} / {d['mean_mm']:.2f} mm "
                     f"({d['max_voxels']:.2f} / {d['mean_voxels']:.2f} voxel) | {solve} | {diff} |")
    return "\n".join(lines)


def result_name(scene: Path, meshers: list[str]) -> str:
    """meshers[_SCENE][_MESHERS]: the scene's file name unless it is the studies' base (or the served scene, which
    the first results were measured on), the meshers unless they are cgal and tetgen."""
    base = {GRID_STUDY_SCENE.stem, SERVED_SCENE.stem}
    return ("meshers" + ("" if scene.stem in base else f"_{scene.stem}")
            + ("" if meshers == DEFAULT_MESHERS else "_" + "_".join(meshers)))


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies compare-meshers", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_flag(ap, what="a phantom scene")
    ap.add_argument("--spacing-mm", type=number("--spacing-mm", minimum=0.05), nargs="+", default=[1.0])
    ap.add_argument("--meshers", nargs="+", choices=tuple(PACKAGE), default=DEFAULT_MESHERS)
    ap.add_argument("--ftetwild", action="store_true", help="also fTetWild (minutes per label map)")
    ap.add_argument("--work", type=Path, default=Path("runs/meshers"), help="folder for the label maps")
    ap.add_argument("--name", help="the result's name (default: from the scene and the meshers, see above)")
    ap.add_argument("--max-solve-tets", type=number("--max-solve-tets", int, minimum=0), default=150_000,
                    help="no linear solve on a larger mesh")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    meshers = args.meshers + (["ftetwild"] if args.ftetwild else [])
    missing = [m for m in meshers if importlib.util.find_spec(PACKAGE[m]) is None]
    for m in missing:
        print(f"skipping {m}: {PACKAGE[m]} is not installed", file=sys.stderr)
    scene = load_scene(args.scene)
    if scene.phantom is None:
        print(f"error: {args.scene} is not a phantom scene", file=sys.stderr)
        return 2
    name = args.name or result_name(args.scene, meshers)
    write = lambda result: results.write(name, result, publish=args.publish)  # noqa: E731 -- after every row
    result = study(scene, spacings_mm=args.spacing_mm, meshers=[m for m in meshers if m not in missing],
                   folder=args.work, max_solve_tets=args.max_solve_tets, on_row=write)
    print(table(result))
    print(f"gmsh phantom, |u| at its 8 markers: {', '.join(f'{u:.3f}' for u in result['phantom_marker_u_mm'])} mm; "
          f"change when every size / 1.3: max {max(result['phantom_refined_marker_difference_mm']):.3f} mm; "
          f"{write(result)}")
    return 0
