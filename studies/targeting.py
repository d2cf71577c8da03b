"""Close the loop on fresh FE: estimate the state from noisy markers and aim the needle, against solves no sweep used.

    python -m studies targeting [--model models/default] [--n 30] [--seed 0] [--lesions 5] [--draws 10] \
        [--plan-points 10] [--out runs/targeting] [--solved-only] [--publish]

At n random points inside the model's envelope (d, beta uniform; each tissue's ln E normal with the scene's std,
clipped to its range) the model's own scene (the manifest's) is solved afresh on the model's mesh: Newton at the
point from the served model's field, else the path from the model's field at 0.9 d, else load-stepped from rest
(each file says which; on the default model the second and the third agreed to 0.006 mm at a point tried both ways). At each point the markers are observed with Gaussian noise (draws per point) and POST /estimate's fit
(service/estimate/fit.py) predicts the lesions: points inside the prostate that are not nodes (centroids of random
prostate tets, fixed by the seed). Configurations: 0.2 mm noise with all markers and with every other one, 0.5 mm
with all, and 0.2 mm with all plus an encoder prior on (d, beta) (0.5 mm, 1 deg, centred on a draw around the
truth). Reported per configuration: the displaced-lesion error (median, 95th percentile), how often the reported
95 % region holds the FE lesion, how often the fit is flagged, and the baselines: the forward model at the true
(d, beta) and nominal stiffness, and "no deformation" (the lesion where it was planned).

Planning (the first --plan-points solved points): POST /plan's aim (service/estimate/aim.py) at the point's d and the
stiffness estimated from all markers at 0.2 mm, at a lesion within reach (a prostate point on the guide's tilt
plane: the random lesions mostly lie off it, out of every pose's reach), then a fresh FE solve at the planned pose
and at naive aiming's pose: the needle ray's distance from the FE-displaced lesion at each.

Each solve is saved under --out (point_NNN.npz, plan_NNN.npz) and never repeated; --solved-only evaluates what is
there without solving more (the JSON says how many of n were solved).
"""  # noqa: E501 -- argparse prints this docstring as it is (--help)

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np
from scipy import stats
from tqdm import tqdm

from studies import results

log = logging.getLogger(__name__)

ENCODER_STD = (0.5, 1.0)  # the guide prior's std: mm, deg
CONFIGS = ({"name": "0.2 mm, 8 markers", "noise_mm": 0.2, "markers": "all", "prior": False},
           {"name": "0.2 mm, 4 markers", "noise_mm": 0.2, "markers": "half", "prior": False},
           {"name": "0.5 mm, 8 markers", "noise_mm": 0.5, "markers": "all", "prior": False},
           {"name": "0.2 mm, 8 markers, encoder prior", "noise_mm": 0.2, "markers": "all", "prior": True})
TARGETS = {"0.2 mm, 8 markers": "median <= 0.12 mm, p95 <= 0.35 mm", "0.2 mm, 4 markers": "median <= 0.2 mm",
           "0.5 mm, 8 markers": "median <= 0.3 mm"}
START_FRACTION = 0.9  # where the path starts from the model's field when Newton at d from it does not converge
PLAN_TOL_MM = 0.5  # the planned needle path must pass this close to the FE-displaced lesion


def draw_points(manifest, n: int, seed: int) -> np.ndarray:
    """(n, 2 + m) states: d, beta uniform in the envelope, theta_i normal with the scene's std, clipped."""
    rng = np.random.default_rng(seed)
    (d_lo, d_hi), (a_lo, a_hi) = manifest.envelope.displacement_mm, manifest.envelope.angle_deg
    cols = [rng.uniform(d_lo, d_hi, n), rng.uniform(a_lo, a_hi, n)]
    for m in manifest.materials.inputs if manifest.materials is not None else []:
        lo, hi = (np.log(e / m.nominal_youngs_kpa) for e in m.youngs_kpa_range)
        cols.append(np.clip(rng.normal(0.0, m.std_percent / 100.0, n), lo, hi))
    return np.column_stack(cols)


def lesion_points(folder, k: int, seed: int) -> np.ndarray:
    """(k, 3) centroids of random prostate tets: inside the prostate, none of them a node."""
    tissue = folder.manifest.mesh.tissues.index("prostate")
    tets = np.flatnonzero(folder.mesh.tissue == tissue)
    pick = np.random.default_rng(seed + 1).choice(tets, size=min(k, len(tets)), replace=False)
    return folder.nodes[folder.tets[pick][:, :4]].mean(axis=1)


def solve(folder, predictor, state: np.ndarray) -> tuple[np.ndarray, str]:
    """The model's scene with E_i = E_i,nominal exp(theta_i), solved on its mesh at (d, beta): (u (n_nodes, 3), the
    start). Newton starts at (d, beta) from the served model's field, as off-grid cases start from the sweep's
    (fem_offline/cases.py: the equilibrium does not depend on the path, up to the contact tolerance); when that
    does not converge in one step, the path from the model's field at START_FRACTION d; then the path from rest."""
    from fem_offline.cases import solve_from
    from fem_offline.fe.continuation import PathState, solve_path
    from fem_offline.fe.newton import ConvergenceError
    from fem_offline.fe.problem import build_problem
    from fem_offline.fe.solve import solve_case
    from fem_offline.material_cases import scaled_scene

    scene = folder.manifest.scene.spec
    tissues = tuple(folder.manifest.materials.tissues) if folder.manifest.materials is not None else ()
    problem = build_problem(scaled_scene(scene, tissues, state[2:]), folder.mesh)
    d, beta = float(state[0]), float(state[1])
    if not problem.superposable:
        def field(d_mm: float) -> np.ndarray:  # the served model's u at (d_mm, beta, theta), (n_dofs,)
            if not tissues:
                return predictor.decode(np.array([[d_mm, beta]]))[0].astype(np.float64).ravel()
            materials = np.zeros((1, 2, len(tissues)), dtype=np.float32)
            materials[0, 0] = state[2:]
            return predictor.decode_std(np.array([[d_mm, beta]]), None, materials)[0][0].astype(np.float64).ravel()

        try:
            u, _ = solve_from(problem, field(d), d, beta)
            return np.asarray(u).reshape(-1, 3), "model"
        except ConvergenceError as exc:
            log.warning("%g mm, %g deg: the start from the model did not converge (%s)", d, beta, exc)
        try:
            start = START_FRACTION * d
            (_, u, _), = solve_path(problem, [d], beta, state=PathState(field(start), start))
            return np.asarray(u).reshape(-1, 3), f"model at {START_FRACTION:g} d"
        except ConvergenceError as exc:
            log.warning("%g mm, %g deg: nor the path from the model at %g d (%s); from rest", d, beta, START_FRACTION,
                        exc)
    u, _ = solve_case(problem, d, beta)
    return np.asarray(u).reshape(-1, 3), "rest"


def solved(path: Path, folder, predictor, state: np.ndarray, *, solve_missing: bool) -> np.ndarray | None:
    """u of `state`, from `path` when saved for this state, else solved and saved; None if it found no equilibrium
    (saved too) or, with solve_missing False, when not saved."""
    from contracts.files import atomic_savez
    from fem_offline.fe.newton import ConvergenceError

    if path.exists():
        with np.load(path) as z:
            if np.allclose(z["state"], state):
                return None if "why" in z.files else z["u"]
    if not solve_missing:
        return None
    try:
        u, started = solve(folder, predictor, state)
    except ConvergenceError as exc:
        atomic_savez(path, state=state, why=str(exc))
        return None
    atomic_savez(path, state=state, u=u, started_from=started)
    return u


def _estimate(predictor, space, pts, n_obs, observed, noise_mm, prior):
    from service.estimate.fit import Problem, estimate, model_sigma_mm

    n = len(space.names)
    mean, std = np.zeros(n), np.full(n, np.inf)
    if space.n_materials:
        std[2:] = [m.std_percent / 100.0 for m in predictor.manifest.materials.inputs]
    if prior is not None:
        mean[:2], std[:2] = prior, ENCODER_STD
    sigma = model_sigma_mm(predictor, pts.reference[n_obs:])  # as POST /estimate adds it to each target's std
    return estimate(predictor, space, Problem(pts, n_obs, observed, np.full(n_obs, noise_mm), mean, std, sigma))


def _covered(err: np.ndarray, cov: np.ndarray) -> bool:
    """Whether the 95 % region of cov (its rank's chi-square) holds err."""
    rank = np.linalg.matrix_rank(cov, tol=1e-12 * max(np.trace(cov), 1e-300))
    return bool(rank and err @ np.linalg.pinv(cov, rcond=1e-9) @ err <= stats.chi2.ppf(0.95, rank))


def evaluate(folder, predictor, fresh: dict[int, np.ndarray], states: np.ndarray, lesions: np.ndarray, *,
             draws: int, seed: int) -> dict:
    """Every configuration's lesion errors, coverage and flags over the solved points; the baselines."""
    from service.estimate.fit import StateSpace, point_set, positions

    space, markers = StateSpace.of(predictor), folder.regions["markers"]
    rng = np.random.default_rng(seed + 2)
    out = {c["name"]: {"errors": [], "covered": [], "flagged": [], "std_d": [], "std_beta": [], "ms": []}
           for c in CONFIGS}
    forward, still = [], []
    for k, u in fresh.items():
        truth_state = states[k]
        for cfg in CONFIGS:
            use = markers if cfg["markers"] == "all" else markers[::2]
            pts = point_set(predictor, node_ids=use, points=lesions)
            true = pts.reference + pts.weights @ u[pts.nodes]  # (len(use) + lesions, 3) FE positions
            row = out[cfg["name"]]
            for _ in range(draws):
                observed = true[:len(use)] + rng.normal(0.0, cfg["noise_mm"], (len(use), 3))
                prior = truth_state[:2] + rng.normal(0.0, 1.0, 2) * ENCODER_STD if cfg["prior"] else None
                t0 = time.perf_counter()
                fit = _estimate(predictor, space, pts, len(use), observed, cfg["noise_mm"], prior)
                row["ms"].append((time.perf_counter() - t0) * 1e3)
                err = fit.targets - true[len(use):]
                row["errors"] += np.linalg.norm(err, axis=1).tolist()
                row["covered"] += [_covered(e, c) for e, c in zip(err, fit.target_covariance)]
                row["flagged"].append(bool(fit.contradiction))
                row["std_d"].append(float(np.sqrt(fit.covariance[0, 0])))
                row["std_beta"].append(float(np.sqrt(fit.covariance[1, 1])))
        pts = point_set(predictor, node_ids=markers[:0], points=lesions)
        true = pts.reference + pts.weights @ u[pts.nodes]
        nominal = np.concatenate([truth_state[:2], np.zeros(space.n_materials)])
        forward += np.linalg.norm(positions(predictor, space, pts, nominal)[0] - true, axis=1).tolist()
        still += np.linalg.norm(lesions - true, axis=1).tolist()
    return _summary(out, np.array(forward), np.array(still), n_lesions=len(lesions), draws=draws)


def _summary(out: dict, forward: np.ndarray, still: np.ndarray, *, n_lesions: int, draws: int) -> dict:
    rows = []
    for name, r in out.items():
        e = np.array(r["errors"])
        if not len(e):
            continue
        # the estimate against the forward model at the true (d, beta), lesion by lesion (same FE point)
        beats = e.reshape(-1, draws, n_lesions) < forward.reshape(-1, 1, n_lesions)
        rows.append({"configuration": name, "median_mm": float(np.median(e)), "p95_mm": float(np.percentile(e, 95)),
                     "max_mm": float(e.max()), "coverage_95": float(np.mean(r["covered"])),
                     "flagged": float(np.mean(r["flagged"])), "beats_forward_nominal": float(beats.mean()),
                     "std_d_mm_median": float(np.median(r["std_d"])),
                     "std_beta_deg_median": float(np.median(r["std_beta"])),
                     "estimate_ms_p50": float(np.percentile(r["ms"], 50)),
                     "estimate_ms_p99": float(np.percentile(r["ms"], 99)), "target": TARGETS.get(name, "")})
    return {"rows": rows, "baselines": {
        "forward_nominal_true_guide": {"median_mm": float(np.median(forward)),
                                       "p95_mm": float(np.percentile(forward, 95))},
        "no_deformation": {"median_mm": float(np.median(still)), "p95_mm": float(np.percentile(still, 95))}}}


def plan_lesion(folder, predictor, k: int, seed: int) -> np.ndarray:
    """(3,) a prostate point that some pose's needle ray passes through at rest: on the guide's tilt plane, at an
    angle inside 0.8 of the envelope's and 4 to 30 mm past the tip (the random lesions mostly lie off that plane,
    out of every pose's reach)."""
    from service.guide import Guide

    guide, rng = Guide.of(folder.manifest), np.random.default_rng(seed + 100 + k)
    prostate = folder.manifest.mesh.tissues.index("prostate")
    lo, hi = folder.manifest.envelope.angle_deg
    for _ in range(1000):
        p = guide.tip_mm + rng.uniform(4.0, 30.0) * guide.direction(0.8 * rng.uniform(lo, hi))
        tet, _ = predictor.locator.locate(p[None])
        if tet[0] >= 0 and folder.mesh.tissue[tet[0]] == prostate:
            return p
    raise ValueError("no prostate point on the guide's tilt plane within reach")


def plan_check(folder, predictor, out: Path, k: int, state: np.ndarray, u: np.ndarray, *,
               solve_missing: bool, seed: int) -> dict | None:
    """Aim at a lesion within reach (plan_lesion) with the point's d and the stiffness estimated from its markers;
    the FE at the planned and the naive pose."""
    from service.estimate import aim
    from service.estimate.fit import StateSpace, point_set, positions
    from service.guide import Guide

    space, guide, markers = StateSpace.of(predictor), Guide.of(folder.manifest), folder.regions["markers"]
    pts = point_set(predictor, node_ids=markers, points=np.zeros((0, 3)))
    noise = np.random.default_rng(seed + 3 + k).normal(0, 0.2, (len(markers), 3))
    observed = pts.reference + pts.weights @ u[pts.nodes] + noise
    theta = _estimate(predictor, space, pts, len(markers), observed, 0.2, None).x[2:]
    lesion = plan_lesion(folder, predictor, k, seed)
    one = point_set(predictor, node_ids=markers[:0], points=lesion[None])
    result = aim.plan(predictor, space, guide, one, theta=theta, theta_std=np.zeros_like(theta),
                      displacement_mm=float(state[0]))
    row = {"point": k, "lesion_mm": lesion.round(3).tolist(), "displacement_mm": float(state[0]),
           "reachable": result.reachable}
    for key, pose in (("planned", result.best), ("naive", result.naive)):
        path = out / f"plan_{k:03d}_{key}.npz"
        fe_state = _saved_pose(path, np.concatenate([[pose.displacement_mm, pose.angle_deg], state[2:]]))
        fe = solved(path, folder, predictor, fe_state, solve_missing=solve_missing)
        if fe is None:
            return None
        d, beta = np.array([fe_state[0]]), np.array([fe_state[1]])
        predicted = positions(predictor, space, one, np.concatenate([fe_state[:2], theta]))[:, 0]
        moved = one.reference + one.weights @ fe[one.nodes]
        row[f"{key}_angle_deg"] = float(fe_state[1])
        row[f"predicted_{key}_miss_mm"] = float(aim.ray_miss(guide, d, beta, predicted)[0][0])
        row[f"fe_{key}_miss_mm"] = float(aim.ray_miss(guide, d, beta, moved)[0][0])
    return row


def _saved_pose(path: Path, wanted: np.ndarray) -> np.ndarray:
    """The pose solved before for this point (same d and stiffness) when `path` holds one, else `wanted`: a plan
    recomputed after a change of the fit's stopping rule may differ in beta by a grid step, and the FE at the pose
    solved is what is checked."""
    if path.exists():
        with np.load(path) as z:
            saved = z["state"]
        if saved.shape == wanted.shape and np.allclose(np.delete(saved, 1), np.delete(wanted, 1)):
            return saved
    return wanted


def run(model: Path, *, n: int, seed: int, n_lesions: int, draws: int, plan_points: int, out: Path,
        solve_missing: bool) -> dict:
    from service.model import Predictor, read_model_folder

    folder = read_model_folder(model)
    predictor = Predictor(folder)
    states, lesions = draw_points(folder.manifest, n, seed), lesion_points(folder, n_lesions, seed)
    out.mkdir(parents=True, exist_ok=True)
    fresh, unsolved, plans = {}, [], []
    # the plan checks interleaved with the points (the first plan_points solved points), so a run stopped early
    # has some of each
    for k, state in enumerate(tqdm(states, desc="fresh FE points", unit="point")):
        u = solved(out / f"point_{k:03d}.npz", folder, predictor, state, solve_missing=solve_missing)
        if u is None:
            if (out / f"point_{k:03d}.npz").exists():
                unsolved.append(k)
            continue
        fresh[k] = u
        if len(fresh) <= plan_points:
            row = plan_check(folder, predictor, out, k, state, u, solve_missing=solve_missing, seed=seed)
            if row is not None:
                plans.append(row)
    data = {"model": folder.manifest.name, "n_points": n, "n_solved": len(fresh), "unsolved": unsolved,
            "seed": seed, "draws_per_point": draws, "lesions_mm": lesions.round(3).tolist(),
            "states": [{"point": k, "displacement_mm": float(s[0]), "angle_deg": float(s[1]),
                        "ln_E": s[2:].round(4).tolist()} for k, s in enumerate(states) if k in fresh],
            "plans": plans}
    if fresh:
        data.update(evaluate(folder, predictor, fresh, states, lesions, draws=draws, seed=seed))
    return data


def report(data: dict) -> str:
    lines = [f"# Estimation and targeting on fresh FE, {data['model']}", "",
             f"{data['n_solved']} of {data['n_points']} random points solved afresh"
             + (f" ({len(data['unsolved'])} found no equilibrium)" if data["unsolved"] else "")
             + f"; {len(data['lesions_mm'])} lesions, {data['draws_per_point']} noise draws per point and "
               "configuration.", ""]
    if data.get("rows"):
        lines += ["| configuration | lesion error, median | p95 | 95 % region holds the FE lesion | flagged | "
                  "beats the forward model at true (d, β) | std d / β (median) | estimate p99 (in process) | issue's "
                  "target |", "|---|---|---|---|---|---|---|---|---|"]
        for r in data["rows"]:
            lines.append(f"| {r['configuration']} | {r['median_mm']:.3f} mm | {r['p95_mm']:.3f} mm | "
                         f"{100 * r['coverage_95']:.1f} % | {100 * r['flagged']:.1f} % | "
                         f"{100 * r['beats_forward_nominal']:.0f} % | {r['std_d_mm_median']:.3f} mm / "
                         f"{r['std_beta_deg_median']:.2f} deg | {r['estimate_ms_p99']:.1f} ms | {r['target']} |")
        b = data["baselines"]
        lines += ["", "Baselines at the same lesions: the forward model at the true (d, β) and nominal stiffness, "
                  f"median {b['forward_nominal_true_guide']['median_mm']:.3f} mm (p95 "
                  f"{b['forward_nominal_true_guide']['p95_mm']:.3f}); no deformation, median "
                  f"{b['no_deformation']['median_mm']:.3f} mm (p95 {b['no_deformation']['p95_mm']:.3f})."]
    if data["plans"]:
        ok = sum(p["fe_planned_miss_mm"] <= PLAN_TOL_MM for p in data["plans"] if p["reachable"])
        reach = sum(p["reachable"] for p in data["plans"])
        lines += ["", f"Planning at {len(data['plans'])} points, each at a lesion on the guide's tilt plane ({reach} "
                  f"reachable): the planned needle path passes within {PLAN_TOL_MM} mm of the FE-displaced lesion at "
                  f"{ok} of {reach}.", "",
                  "| point | lesion (mm) | d (mm) | planned β | predicted miss | FE miss, planned | naive β | "
                  "predicted miss, naive | FE miss, naive |", "|---|---|---|---|---|---|---|---|---|"]
        for p in data["plans"]:
            lines.append(f"| {p['point']} | {p['lesion_mm']} | {p['displacement_mm']:.2f} | "
                         f"{p['planned_angle_deg']:.2f} | {p['predicted_planned_miss_mm']:.3f} mm | "
                         f"{p['fe_planned_miss_mm']:.3f} mm | {p['naive_angle_deg']:.2f} | "
                         f"{p['predicted_naive_miss_mm']:.3f} mm | {p['fe_naive_miss_mm']:.3f} mm |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m studies targeting", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=Path("models/default"))
    ap.add_argument("--n", type=int, default=30, help="random points solved afresh (default 30)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--lesions", type=int, default=5, help="lesion points inside the prostate (default 5)")
    ap.add_argument("--draws", type=int, default=10, help="noise draws per point and configuration (default 10)")
    ap.add_argument("--plan-points", type=int, default=10, help="points where the plan is checked on fresh FE")
    ap.add_argument("--out", type=Path, default=Path("runs/targeting"), help="the solves (resumable)")
    ap.add_argument("--solved-only", action="store_true", help="evaluate the saved solves; solve nothing")
    ap.add_argument("-v", "--verbose", action="store_true")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING)
    if args.n < 1 or args.lesions < 1 or args.draws < 1:
        print("error: --n, --lesions and --draws: at least 1", file=sys.stderr)
        return 2
    try:
        data = run(args.model, n=args.n, seed=args.seed, n_lesions=args.lesions, draws=args.draws,
                   plan_points=args.plan_points, out=args.out, solve_missing=not args.solved_only)
    except (ValueError, FileNotFoundError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    data["report_md"] = report(data)
    print(data["report_md"])
    print(f"wrote {results.write('targeting', data, publish=args.publish)}")
    return 0
