"""Does a material model's std hold over the box? Monte Carlo over fresh FE at the default sigma, judged by ratios.

    python -m studies design-mc [--model models/default] [--n 32] [--seed 0] [--workers 2] \\
        [--out runs/design_mc] [--solved-only] [--publish]

At each material point (the nominal stiffnesses, a benign gland, one near the box's hardest corner) and guide case,
theta_i = ln(E_i / E_i,nominal) is drawn around the point from a normal distribution with the std every request
gets by default (the scene's std_percent: sigma_i = std_percent / 100, contracts.materials.sigma_ln_e), kept when
the box holds its ratios (what the service answers; draws it refuses are drawn again: the distribution truncated
to the box) and moved to the box's point with those ratios (contracts.materials.ratio_point). Each draw is solved
afresh on the model's mesh (studies.targeting.solve: Newton from the model's field at the draw). The model answers
at the point, with its std at sigma (the graph's own Jacobian, or the first-order S_i of a first-order model).

Per point and guide case, at the markers and on the prostate surface:
  std     the draws' std per node and component (about their mean), against the model's std there: their ratio at
          the node where the model's std is largest (the issue asks for 0.85 to 1.15; a sample std of n draws is
          itself uncertain by about 1 / sqrt(2 (n - 1)), 13 % at 32);
  cover   the share of (draw, node) pairs whose fresh displacement lies within HALO_SIGMAS x |std| (the radius the
          viewer and OpenIGTLink draw) of the model's answer: the issue asks for 90 to 98 %.
The answer's error includes the surrogate's own: this is what a user of the answer and its std faces.
Each draw's solve is saved under --out and never repeated.
"""

from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path

import numpy as np

from studies import results

log = logging.getLogger(__name__)

REGIONS = ("markers", "prostate_surface")
GUIDE_CASES = ((10.0, 0.0), (10.0, 10.0), (6.0, -5.0))
# E as a factor of its nominal; tissues left out are nominal. The hardest corner of the patient box is a soft
# gland and fat against a stiff wall and bladder (docs: Hard cases); "near" it is 0.8 of the way in ln E.
MATERIAL_POINTS = {"nominal": {}, "benign gland (35 kPa)": {"prostate": 35.0 / 65.89},
                   "near the hardest corner": {"prostate": 0.4**0.8, "adipose": 0.5**0.8, "rectal_wall": 1.2**0.8,
                                               "bladder": 3.0**0.8}}
COVER_TARGET = (0.90, 0.98)
STD_TARGET = (0.85, 1.15)


def point_theta(info, factors: dict[str, float]) -> np.ndarray:
    """theta of a material point (tissue -> factor of its nominal E), moved into the box by its ratios."""
    from contracts.materials import ratio_point

    lo, hi = info.log_box
    theta = [math.log(factors.get(t, 1.0)) for t in info.tissues]
    return np.array(ratio_point(theta, lo, hi, info.tissues))


def draw_thetas(info, centre: np.ndarray, sigma: np.ndarray, n: int, seed: int) -> tuple[np.ndarray, int]:
    """n draws around `centre` at `sigma`, each kept when the box holds its ratios and moved to its canonical point;
    (draws (n, m), how many were refused on the way)."""
    from contracts.materials import ratio_point, ratio_shift_interval

    lo, hi = info.log_box
    rng, kept, refused = np.random.default_rng(seed), [], 0
    while len(kept) < n:
        theta = centre + sigma * rng.normal(size=len(centre))
        a, b = ratio_shift_interval(theta.tolist(), lo, hi)
        if a > b:
            refused += 1
            continue
        kept.append(ratio_point(theta.tolist(), lo, hi, info.tissues))
    return np.array(kept), refused


def compare(fresh: np.ndarray, answer: np.ndarray, std: np.ndarray, halo_sigmas: float) -> dict:
    """fresh (n, k, 3) draws' u against the model's answer (k, 3) and std (k, 3) at k nodes: the ratio of the draws'
    std to the model's at the node of the model's largest std, the largest of each, and the share of (draw, node)
    pairs within halo_sigmas x |std| of the answer."""
    mc = fresh.std(axis=0, ddof=1)  # (k, 3)
    at = int(np.argmax(np.linalg.norm(std, axis=1)))
    radius = halo_sigmas * np.linalg.norm(std, axis=1)  # (k,)
    inside = np.linalg.norm(fresh - answer, axis=2) <= radius
    return {"mc_std_mm": float(np.linalg.norm(mc[at])), "model_std_mm": float(np.linalg.norm(std[at])),
            "ratio": float(np.linalg.norm(std[at]) / max(np.linalg.norm(mc[at]), 1e-300)),
            "mc_std_max_mm": float(np.linalg.norm(mc, axis=1).max()),
            "model_std_max_mm": float(np.linalg.norm(std, axis=1).max()), "covered": float(inside.mean()),
            "answer_error_max_mm": float(np.linalg.norm(fresh.mean(axis=0) - answer, axis=1).max())}


def _solve_draw(model: str, path: str, state: list[float], solve_missing: bool):
    from service.model import Predictor, read_model_folder
    from studies.targeting import solved

    folder = read_model_folder(model)
    return solved(Path(path), folder, Predictor(folder), np.asarray(state), solve_missing=solve_missing)


def run(model: Path, *, n: int, seed: int, out: Path, workers: int, solve_missing: bool,
        points: dict = MATERIAL_POINTS, cases=GUIDE_CASES) -> dict:
    from contracts.materials import HALO_SIGMAS
    from service.model import Predictor, read_model_folder

    folder = read_model_folder(model)
    info = folder.manifest.materials
    if info is None:
        raise ValueError(f"--model: {model} takes no material inputs; there is no std to check")
    predictor = Predictor(folder)
    sigma = np.array([m.std_percent / 100.0 for m in info.inputs])
    out.mkdir(parents=True, exist_ok=True)
    jobs = {}
    for p, (name, factors) in enumerate(points.items()):
        centre = point_theta(info, factors)
        thetas, refused = draw_thetas(info, centre, sigma, n, seed + p)
        for d, beta in cases:
            for k, theta in enumerate(thetas):
                jobs[(name, d, beta, k)] = (out / f"p{p}_{d:g}_{beta:g}_{seed}_{k:03d}.npz", [d, beta, *theta])
        jobs[(name, "centre")] = (centre, refused, thetas)
    draws_todo = [(key, v) for key, v in jobs.items() if key[1] != "centre"]
    from tqdm import tqdm

    if workers == 1:  # in this process
        solved_u = {key: _solve_draw(str(model), str(path), state, solve_missing)
                    for key, (path, state) in tqdm(draws_todo, desc="draws", unit="solve")}
    else:  # spawned, one thread each: a forked child of a process running onnxruntime's threads can hang
        from fem_offline.sweep import single_threaded_pool

        with single_threaded_pool(workers) as pool:
            futures = {key: pool.submit(_solve_draw, str(model), str(path), state, solve_missing)
                       for key, (path, state) in draws_todo}
            solved_u = {key: f.result() for key, f in tqdm(futures.items(), desc="draws", unit="solve")}
    node_sets = {r: np.asarray(folder.mesh.node_sets[r]) for r in REGIONS}
    rows = []
    for name in points:
        centre, refused, thetas = jobs[(name, "centre")]
        for d, beta in cases:
            fresh = [solved_u[(name, d, beta, k)] for k in range(n)]
            ok = [u for u in fresh if u is not None]
            row = {"point": name, "theta": centre.round(4).tolist(), "displacement_mm": d, "angle_deg": beta,
                   "draws": n, "solved": len(ok), "refused_outside_box": refused,
                   "drawn_sigma": thetas.std(axis=0, ddof=1).round(4).tolist()}
            if len(ok) >= 3:
                mats = np.stack([centre, sigma])[None].astype(np.float32)
                answer, std = (a[0].astype(np.float64) for a in predictor.decode_std(np.array([[d, beta]]), None, mats))
                for r, ids in node_sets.items():
                    row[r] = compare(np.stack(ok)[:, ids], answer[ids], std[ids], HALO_SIGMAS)
            rows.append(row)
    return {"model": folder.manifest.name, "n_draws": n, "seed": seed, "sigma": sigma.tolist(),
            "tissues": list(info.tissues), "halo_sigmas": HALO_SIGMAS,
            "sampling_uncertainty": 1 / math.sqrt(2 * (n - 1)),
            "targets": {"std_ratio": STD_TARGET, "covered": COVER_TARGET}, "rows": rows}


def report(data: dict) -> str:
    lines = [f"# The std over the box: Monte Carlo over fresh FE, {data['model']}", "",
             f"{data['n_draws']} draws per point and guide case at sigma of ln E {data['sigma']} "
             f"({', '.join(data['tissues'])}), the distribution truncated to the box by ratios. A sample std of "
             f"{data['n_draws']} draws is itself uncertain by about {100 * data['sampling_uncertainty']:.0f} %.", "",
             "| point | d, beta | solved | markers: model std / MC std | markers: within "
             f"{data['halo_sigmas']:g} std | prostate surface: model / MC std | within {data['halo_sigmas']:g} std |",
             "|---|---|---|---|---|---|---|"]
    for r in data["rows"]:
        cells = []
        for region in REGIONS:
            v = r.get(region)
            cells += (["not enough solved", ""] if v is None else
                      [f"{v['model_std_mm']:.4f} / {v['mc_std_mm']:.4f} mm ({v['ratio']:.2f})",
                       f"{100 * v['covered']:.1f} %"])
        lines.append(f"| {r['point']} | {r['displacement_mm']:g} mm, {r['angle_deg']:g} deg | {r['solved']} of "
                     f"{r['draws']} | " + " | ".join(cells) + " |")
    lo, hi = data["targets"]["std_ratio"]
    clo, chi = data["targets"]["covered"]
    lines += ["", f"Targets: model / MC std {lo:g} to {hi:g}; {100 * clo:.0f} to {100 * chi:.0f} % within "
              f"{data['halo_sigmas']:g} std."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from contracts.cli import number

    ap = argparse.ArgumentParser(prog="python -m studies design-mc", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=Path("models/default"))
    ap.add_argument("--n", type=number("--n", int, minimum=3), default=32, help="draws per point and case")
    ap.add_argument("--seed", type=number("--seed", int), default=0)
    ap.add_argument("--workers", type=number("--workers", int, minimum=1), default=2)
    ap.add_argument("--out", type=Path, default=Path("runs/design_mc"), help="the solved draws (resumable)")
    ap.add_argument("--solved-only", action="store_true", help="evaluate the saved draws, solve none")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    if not (args.model / "manifest.json").is_file():
        ap.error(f"--model: {args.model} is not a model folder")
    try:
        data = run(args.model, n=args.n, seed=args.seed, out=args.out, workers=args.workers,
                   solve_missing=not args.solved_only)
    except ValueError as exc:
        ap.error(str(exc))
    data["report_md"] = report(data)
    print(data["report_md"])
    print(f"wrote {results.write('design_mc', data, publish=args.publish)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
