"""Marker motion of each anatomical variant at one guide push (issue #14): label map -> mesh -> FE, side by side.

    python -m studies anatomy-table [--variants small medium large] [--work runs/anatomy] [--publish]

For each fem_offline/scenes/anatomy/<variant>.toml: voxelise the phantom at --spacing-mm into
<work>/<variant>/labels.nii.gz with its label-map scene (`python -m studies make-labelmap`), then run

    python -m fem_offline mesh  --scene <work>/<variant>/scene.toml --out <work>/<variant>/mesh.npz
    python -m fem_offline solve --scene <work>/<variant>/scene.toml --mesh <work>/<variant>/mesh.npz \\
        --displacement-mm 10 --angle-deg 0 --out <work>/<variant>/d10_b0.npz

with the scene's physics and mesh sizes (default.toml's: nonlinear, the guide tip in frictionless
contact). A step whose file exists is skipped, so the solves can be run one at a time by hand or by
--variants. Prints |u| at the 8 prostate markers of each variant (marker k is in the same octant of
every prostate) with the variants' anatomy, and writes them as the result anatomy_table.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from tqdm import tqdm

from contracts.cli import number
from studies import results
from studies.options import SCENES

VARIANTS_DIR = SCENES / "anatomy"


def prepare(variant: str, folder: Path, spacing_mm: float) -> Path:
    """The variant's label map and label-map scene in `folder` (kept when already there); the scene's path."""
    from fem_offline.scene import load_scene
    from studies.make_labelmap import write_labelmap

    scene_path = folder / "scene.toml"
    if not scene_path.exists():
        scene = load_scene(VARIANTS_DIR / f"{variant}.toml")
        write_labelmap(scene, spacing_mm, folder, name=scene.name)
    return scene_path


def run_cli(*argv) -> None:
    """`python -m fem_offline ...` in this process; SystemExit on failure."""
    from fem_offline.__main__ import main

    print("$ python -m fem_offline " + " ".join(map(str, argv)), flush=True)
    if main([str(a) for a in argv]) != 0:
        raise SystemExit(f"python -m fem_offline {argv[0]} failed")


def solved(folder: Path, scene_path: Path) -> bool:
    """Whether folder/d10_b0.npz holds this scene's answer; a stale one (another scene hash: the physics
    or the guide's seat changed since) is removed so that it is solved again."""
    from fem_offline.scene import load_scene

    case = folder / "d10_b0.npz"
    if not case.exists():
        return False
    with np.load(case) as z:
        stale = "scene_sha256" not in z.files or str(z["scene_sha256"]) != load_scene(scene_path).sha256()
    if stale:
        print(f"{case}: solved for another scene (physics or guide seat changed); solving again", flush=True)
        case.unlink()
    return not stale


def row(variant: str, folder: Path, *, displacement_mm: float, angle_deg: float) -> dict:
    """The variant's anatomy, mesh and marker motion from the files in `folder`."""
    from fem_offline.scene.anatomy import describe
    from fem_offline.fe.guide import seat
    from fem_offline.geometry.meshing import load_or_build_mesh
    from fem_offline.geometry.regions import marker_names
    from fem_offline.scene import load_scene

    scene = load_scene(folder / "scene.toml")
    mesh = load_or_build_mesh(scene, folder / "mesh.npz")
    with np.load(folder / "d10_b0.npz") as z:
        u, record = z["displacement"], {k: float(z[k]) for k in ("newton_iterations", "min_det_f", "seconds")}
        if not np.array_equal(z["reference_positions"], mesh.nodes):
            raise SystemExit(f"{folder}: d10_b0.npz was solved on another mesh than mesh.npz; delete it and run again")
    markers = mesh.node_sets["markers"]
    tip = seat(mesh, scene.guide)  # where the push is centred on this mesh
    prostate = mesh.nodes[np.unique(mesh.tets[mesh.tissue == mesh.tissue_names.index("prostate")])]
    return {
        "variant": variant, "scene": f"fem_offline/scenes/anatomy/{variant}.toml",
        "anatomy": describe(load_scene(VARIANTS_DIR / f"{variant}.toml").phantom),
        "mesh": {"tets": len(mesh.tets), "nodes": len(mesh.nodes),
                 "prostate_length_mm": float(np.ptp(prostate[:, 0])),  # on the mesh, against the ellipsoid's
                 "tip_snapped_mm": np.round(tip.point, 3).tolist(), "tip_snap_distance_mm": round(tip.offset_mm, 3),
                 "tip_nearest_node": tip.node, "tip_snap_to": scene.guide.snap_to},
        "displacement_mm": displacement_mm, "angle_deg": angle_deg, "solve": record,
        "markers": {name: {"position_mm": np.round(mesh.nodes[i], 3).tolist(), "u_mm": np.round(u[i], 4).tolist(),
                           "abs_u_mm": round(float(np.linalg.norm(u[i])), 4)}
                    for name, i in zip(marker_names(), markers)},
    }


def table(rows: list[dict]) -> str:
    """The markdown table: one column per variant, anatomy first, then |u| per marker."""
    a = [r["anatomy"] for r in rows]
    lines = ["| | " + " | ".join(r["variant"] for r in rows) + " |", "|---" * (len(rows) + 1) + "|"]
    fields = [("prostate length (mesh), mm",
               lambda r, x: f"{x['prostate_length_mm']:g} ({r['mesh']['prostate_length_mm']:.1f})"),
              ("prostate size x, y, z, mm", lambda r, x: ", ".join(f"{v:g}" for v in x["prostate_size_mm"])),
              ("prostate centre offset x, y, z, mm",
               lambda r, x: ", ".join(f"{v:+g}" for v in x["prostate_offset_mm"])),
              ("rectal wall, mm", lambda r, x: f"{x['rectal_wall_mm']:g}"),
              ("lumen to prostate, mm", lambda r, x: f"{x['prostate_to_lumen_mm']:.1f}"),
              ("tets", lambda r, x: f"{r['mesh']['tets']:,}"),
              ("guide tip snapped to x, y, z, mm",
               lambda r, x: ", ".join(f"{v:.1f}" for v in r["mesh"]["tip_snapped_mm"]))]
    lines += [f"| {name} | " + " | ".join(f(r, x) for r, x in zip(rows, a)) + " |" for name, f in fields]
    for m in rows[0]["markers"]:
        lines.append(f"| \\|u\\| {m}, mm | " + " | ".join(f"{r['markers'][m]['abs_u_mm']:.2f}" for r in rows) + " |")
    lines.append("| solve: Newton iterations, s | " + " | ".join(
        f"{r['solve']['newton_iterations']:.0f}, {r['solve']['seconds']:.0f}" for r in rows) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies anatomy-table", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variants", nargs="+", choices=("small", "medium", "large"), default=["small", "medium", "large"])
    ap.add_argument("--work", type=Path, default=Path("runs/anatomy"))
    ap.add_argument("--spacing-mm", type=number("--spacing-mm", minimum=0.05), default=1.0)
    ap.add_argument("--prepare-only", action="store_true", help="write the label maps and meshes, solve nothing")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    d, beta = 10.0, 0.0
    for v in tqdm(args.variants, desc="variants", unit="variant"):
        folder = args.work / v
        scene_path = prepare(v, folder, args.spacing_mm)
        if not (folder / "mesh.npz").exists():
            run_cli("mesh", "--scene", scene_path, "--out", folder / "mesh.npz")
        if not args.prepare_only and not solved(folder, scene_path):
            run_cli("solve", "--scene", scene_path, "--mesh", folder / "mesh.npz", "--displacement-mm", d,
                    "--angle-deg", beta, "--out", folder / "d10_b0.npz")
    if args.prepare_only:
        return 0
    rows = [row(v, args.work / v, displacement_mm=d, angle_deg=beta) for v in args.variants]
    print(f"\nguide push {d:g} mm at beta = {beta:g} deg, {args.spacing_mm:g} mm label maps, "
          "the scenes' physics and mesh sizes\n")
    print(table(rows))
    path = results.write("anatomy_table", {"spacing_mm": args.spacing_mm, "rows": rows}, publish=args.publish)
    print(f"\nwrote {path}")
    return 0
