"""Does first-order propagation give the answer's spread? Monte Carlo over fresh FE solves against it.

    python -m studies material-mc --sweep runs/default [--scene fem_offline/scenes/default.toml] \
        [--case 10/0] [--n 24] [--seed 0] [--model models/default] [--out runs/material_mc] [--publish]

At a guide position of a material sweep (a grid point), each tissue's theta_i = ln(E_i / E_i,nominal) is drawn
independently from a normal distribution with the std the scene states (std_percent, as the service reads it:
contracts.materials.sigma_ln_e, sigma_i = std_percent / 100), clipped to the declared range, n times. Each draw is
solved afresh (the continuation of fem_offline.material_cases, from the nominal state at that position). Per node,
the standard deviation of the n fresh displacements (per component, then the largest over x, y, z) is compared with
the first-order one, sqrt(sum_i sigma_i^2 S_i^2), where sigma_i is the std of the draws actually made (the clipping narrows them):
the largest gap and the ratio at the markers, on the prostate surface and at every node. The served model's
displacement_std (--model, at the same sigma) is compared the same way. With n draws, a sample std is itself
uncertain by about 1 / sqrt(2 (n - 1)) of its size (15 % at n = 24): the table says so. Each draw (solved or not) is saved
under --out; a rerun solves only the missing ones.
"""  # noqa: E501 -- argparse prints this docstring as it is (--help)

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from studies import results

REGIONS = ("markers", "prostate_surface", "all_nodes")


def draws(scene, n: int, seed: int) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """(tissues, theta (n, m) clipped to the ranges, the scene's sigma_i)."""
    from contracts.materials import sigma_ln_e

    tissues = tuple(scene.materials)
    sigma = np.array([sigma_ln_e(std=scene.materials[t].std_percent, value=100.0) for t in tissues])
    lo, hi = (np.array([np.log(scene.materials[t].youngs_kpa_range[j] / scene.tissues[t].youngs) for t in tissues])
              for j in (0, 1))
    theta = np.random.default_rng(seed).normal(size=(n, len(tissues))) * sigma
    return tissues, np.clip(theta, lo, hi), sigma


def run(scene, sweep: Path, case: tuple[float, float], n: int, seed: int, out: Path, model: Path | None) -> dict:
    """The comparison at `case` for a Scene (fem_offline.scene) and its material sweep; draws saved under `out`."""
    from contracts.files import atomic_savez
    from contracts.mesh import read_mesh
    from fem_offline.fe.newton import ConvergenceError
    from fem_offline.material_cases import _at, _fresh, nominal_from_sweep

    if not scene.materials:
        raise ValueError(f"--scene: {scene.name} has no [materials]")
    mesh = read_mesh(Path(sweep) / "mesh.npz")
    d, beta = case
    tissues, theta, sigma = draws(scene, n, seed)
    snapshot, sens = nominal_from_sweep(sweep, tissues, d, beta)
    out.mkdir(parents=True, exist_ok=True)
    nominal_file = out / f"nominal_{d:g}_{beta:g}.npz"
    if nominal_file.exists():
        with np.load(nominal_file) as z:
            nominal = (z["u"], z["multipliers"] if z["multipliers"].size else None)
    else:
        nominal = _at(scene, mesh, d, beta, snapshot, None)
        atomic_savez(nominal_file, u=nominal[0], multipliers=np.array([]) if nominal[1] is None else nominal[1])
    fresh, failed = [], []
    for k, t in enumerate(tqdm(theta, desc=f"draws at {d:g} mm / {beta:g} deg", unit="solve")):
        f = out / f"draw_{d:g}_{beta:g}_{seed}_{k:03d}.npz"
        if f.exists():
            with np.load(f) as z:
                if np.allclose(z["theta"], t):
                    if "why" in z.files:  # a draw without equilibrium is a finding too: not solved again
                        failed.append({"theta": t.round(4).tolist(), "why": str(z["why"])})
                    else:
                        fresh.append(z["u"])
                    continue
        try:
            u = _fresh(scene, mesh, tissues, t, nominal, sens, d, beta)
        except ConvergenceError as exc:
            failed.append({"theta": t.round(4).tolist(), "why": str(exc)})
            atomic_savez(f, theta=t, why=str(exc))
            continue
        atomic_savez(f, u=u, theta=t)
        fresh.append(u)
    if len(fresh) < 3:
        raise ValueError(f"only {len(fresh)} of {n} draws solved; too few for a spread")
    used = np.array([t for t in theta if not any(np.allclose(t, fl["theta"], atol=1e-4) for fl in failed)])
    sigma_used = used.std(axis=0, ddof=1)
    S = np.stack([sens[t] for t in tissues])  # (m, n_nodes, 3)
    mc = np.stack(fresh).std(axis=0, ddof=1).max(axis=1)  # (n_nodes,)
    first = np.sqrt(np.einsum("m,mnk->nk", sigma_used**2, S**2)).max(axis=1)
    linear = nominal[0] + np.einsum("pm,mnk->pnk", used, S)
    per_draw = np.linalg.norm(linear - np.stack(fresh), axis=2)  # (draws, n_nodes)
    lin_err = per_draw.max(axis=0)
    ids = {r: (np.asarray(mesh.node_sets[r]) if r != "all_nodes" else slice(None)) for r in REGIONS}
    row = {r: {"mc_std_max_mm": float(mc[i].max()), "first_order_std_max_mm": float(first[i].max()),
               "gap_max_mm": float(np.abs(mc[i] - first[i]).max()),
               "ratio_at_largest": float(mc[i][np.argmax(first[i])] / max(first[i].max(), 1e-30)),
               "first_order_answer_error_max_mm": float(lin_err[i].max())} for r, i in ids.items()}
    data = {"scene": scene.name, "sweep": str(sweep), "case": {"displacement_mm": d, "angle_deg": beta},
            "n_draws": n, "n_solved": len(fresh), "seed": seed, "tissues": list(tissues),
            "sigma_stated": sigma.round(4).tolist(), "sigma_drawn": sigma_used.round(4).tolist(),
            "sampling_uncertainty": float(1 / np.sqrt(2 * (len(fresh) - 1))), "regions": row, "unsolved": failed,
            "draws": [{"theta": t.round(4).tolist(), "first_order_error_markers_mm": float(e[ids["markers"]].max()),
                       "first_order_error_all_nodes_mm": float(e.max())} for t, e in zip(used, per_draw)]}
    if model is not None:
        from contracts.model import onnx_session, read_manifest

        names = read_manifest(model).materials.tissues
        if names != list(tissues):
            raise ValueError(f"--model: {model} takes {names}, the scene declares {list(tissues)}")
        served = onnx_session(Path(model) / "model.onnx").run(["displacement_std"], {
            "guide": np.array([[d, beta]], np.float32), "materials": np.zeros((1, len(tissues)), np.float32),
            "materials_std": sigma_used[None].astype(np.float32)})[0][0].max(axis=1)
        for r, i in ids.items():
            row[r]["model_std_max_mm"] = float(served[i].max())
            row[r]["model_gap_max_mm"] = float(np.abs(mc[i] - served[i]).max())
    return data


def report(data: dict) -> str:
    c = data["case"]
    lines = [f"# Monte Carlo against first-order propagation, {c['displacement_mm']:g} mm / {c['angle_deg']:g} deg", "",
             f"{data['n_solved']} of {data['n_draws']} draws solved afresh; sigma of ln E per tissue "
             f"({', '.join(data['tissues'])}): stated {data['sigma_stated']}, drawn {data['sigma_drawn']} (clipped to "
             f"the ranges). A sample std of {data['n_solved']} draws is itself uncertain by about "
             f"{100 * data['sampling_uncertainty']:.0f} %.", "",
             "| region | MC std, max | first-order std, max | largest gap | MC / first order at its largest | "
             "first-order answer vs fresh, max | served model's std, max |", "|---|---|---|---|---|---|---|"]
    for r, v in data["regions"].items():
        model = f"{v['model_std_max_mm']:.4f} mm" if "model_std_max_mm" in v else "not run"
        lines.append(f"| {r.replace('_', ' ')} | {v['mc_std_max_mm']:.4f} mm | {v['first_order_std_max_mm']:.4f} mm | "
                     f"{v['gap_max_mm']:.4f} mm | {v['ratio_at_largest']:.3f} | "
                     f"{v['first_order_answer_error_max_mm']:.4f} mm | {model} |")
    if data.get("draws"):
        markers = np.array([dr["first_order_error_markers_mm"] for dr in data["draws"]])
        worst = data["draws"][int(np.argmax(markers))]
        lines += ["", f"The first-order answer is within 0.02 mm of the fresh solve at the markers for "
                  f"{int((markers <= 0.02).sum())} of {len(markers)} draws; the worst, theta {worst['theta']}, is off "
                  f"by {worst['first_order_error_markers_mm']:.4f} mm there and "
                  f"{worst['first_order_error_all_nodes_mm']:.3f} mm at its worst node."]
    if data["unsolved"]:
        lines += ["", f"{len(data['unsolved'])} draws found no equilibrium and are left out: "
                  + "; ".join(str(u["theta"]) for u in data["unsolved"])]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m studies material-mc", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=Path("fem_offline/scenes/default.toml"))
    ap.add_argument("--sweep", type=Path, required=True, help="the scene's material sweep (its mesh and S_i)")
    ap.add_argument("--case", default="10/0", help="guide position D/A, a grid point of the sweep (default 10/0)")
    ap.add_argument("--n", type=int, default=24, help="draws (default 24)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--model", type=Path, help="a material model of the sweep: its displacement_std compared too")
    ap.add_argument("--out", type=Path, default=Path("runs/material_mc"), help="the solved draws (resumable)")
    ap.add_argument("-v", "--verbose", action="store_true")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING)
    try:
        case = tuple(float(v) for v in args.case.split("/"))
        if len(case) != 2:
            raise ValueError
    except ValueError:
        print(f"error: --case: expected DISPLACEMENT_MM/ANGLE_DEG like 10/0, got {args.case!r}", file=sys.stderr)
        return 2
    if args.n < 3:
        print("error: --n: at least 3 draws", file=sys.stderr)
        return 2
    from fem_offline.scene import SceneError, load_scene

    try:
        data = run(load_scene(args.scene), args.sweep, case, args.n, args.seed, args.out, args.model)
    except (SceneError, ValueError, FileNotFoundError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    data["report_md"] = report(data)
    print(data["report_md"])
    print(f"wrote {results.write('material_mc', data, publish=args.publish)}")
    return 0
