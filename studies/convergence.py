"""Grid convergence at the quantities users ask for: Roache's grid convergence index (ASME V&V 20).

Three meshes whose sizes are scaled by ratios r32 = h_coarse / h_medium and r21 = h_medium / h_fine
(both >= 1.3, equal in a systematic refinement) give, for a scalar f with values f3, f2, f1
(coarse, medium, fine):

    e32 = f3 - f2, e21 = f2 - f1, R = e21 / e32
    0 < R < 1: monotonic convergence; R < 0: oscillatory; R >= 1: monotonic divergence
    observed order       p = ln(1 / R) / ln r                      (monotonic convergence, r21 = r32 = r)
                         p = (ln(1 / R) + ln((r21^p - 1) / (r32^p - 1))) / ln r21, by fixed point
                         (r21 != r32; Celik et al. 2008, the procedure ASME V&V 20 follows)
    Richardson estimate  f_ext = f1 + (f1 - f2) / (r21^p - 1)
    GCI (fine, absolute) = Fs |f1 - f2| / (r21^q - 1),  Fs = 1.25,  q = min(p, P_FORMAL)
    GCI (medium)         = Fs |f2 - f3| / (r32^q - 1)
Capping the order at the scheme's (P_FORMAL) keeps a lucky, too-high observed p from shrinking the
band. Without monotonic convergence no order can be observed: the band is then Fs times the spread
of the three values, a heuristic that says "not in the asymptotic range" rather than a bound.

For a whole field (every point of the prostate surface) the order p of its mean is used at each
point: GCI_i = Fs |u1_i - u2_i| / (r^p - 1), the error bound of the fine field at that point.
The fields are compared at fixed reference points, located in each mesh (contracts.interpolate).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.files import atomic_savez
from contracts.mesh import read_mesh
from contracts.interpolate import interpolation_matrix

from fem_offline.fe import guide as guide_mod
from fem_offline.fe.continuation import PathState, solve_path
from fem_offline.fe.problem import Problem
from fem_offline.scene import Scene

log = logging.getLogger(__name__)

SAFETY = 1.25  # Roache's factor of safety for three-grid studies
P_FORMAL = 2.0  # P2 tets: displacement error O(h^3) in L2 but O(h^2) pointwise near the guide's kinks
MIN_RATIO = 1.3  # Roache's smallest size ratio between levels
NEAR_TIP_MM = 8.0  # the near-tip zone, reported apart from the rest


@dataclass(frozen=True)
class Richardson:
    """One scalar on three meshes (coarse, medium, fine) and what they say about its converged value."""

    values: tuple[float, float, float]  # f3, f2, f1
    kind: str  # "monotonic" (converging), "oscillatory", "divergent" or "converged" (no change)
    order: float  # observed p (nan unless monotonic)
    extrapolated: float  # Richardson estimate (nan unless monotonic)
    gci_fine: float  # absolute error band of the fine value, same unit as f
    gci_medium: float


def _ratios(ratio: float | tuple[float, float]) -> tuple[float, float]:
    """(r32, r21) from one constant ratio or the pair."""
    return (float(ratio), float(ratio)) if np.isscalar(ratio) else (float(ratio[0]), float(ratio[1]))


def observed_order(e32: float, e21: float, ratio: float | tuple[float, float]) -> float:
    """p from two monotonically shrinking changes (0 < e21 / e32 < 1) on meshes refined by (r32, r21)."""
    r32, r21 = _ratios(ratio)
    p = np.log(e32 / e21) / np.log(r21)
    for _ in range(100):  # converges in a few iterations for r32 ~ r21
        q = np.log((r21**p - 1.0) / (r32**p - 1.0))
        p, last = (np.log(e32 / e21) + q) / np.log(r21), p
        if abs(p - last) < 1e-12:
            break
    return float(p)


def richardson(coarse: float, medium: float, fine: float, ratio: float | tuple[float, float]) -> Richardson:
    """Observed order, Richardson extrapolation and GCI of three values on meshes refined by `ratio`
    (one constant ratio, or (r32, r21))."""
    r32, r21 = _ratios(ratio)
    e32, e21 = coarse - medium, medium - fine
    values = (float(coarse), float(medium), float(fine))
    if e21 == 0 and e32 == 0:
        return Richardson(values, "converged", np.nan, fine, 0.0, 0.0)
    if e32 * e21 <= 0 or abs(e21) >= abs(e32):
        spread = SAFETY * (max(values) - min(values))
        kind = "oscillatory" if e32 * e21 <= 0 else "divergent"
        return Richardson(values, kind, np.nan, np.nan, spread, spread)
    p = observed_order(e32, e21, (r32, r21))
    q = min(p, P_FORMAL)
    return Richardson(values, "monotonic", p, fine + (fine - medium) / (r21**p - 1.0),
                      SAFETY * abs(e21) / (r21**q - 1.0), SAFETY * abs(e32) / (r32**q - 1.0))


def field_gci(coarse: np.ndarray, medium: np.ndarray, fine: np.ndarray, ratio: float | tuple[float, float],
              order: Richardson | None = None, level: str = "fine") -> tuple[np.ndarray, Richardson]:
    """Per-point error band (k,) in mm of the fine field (or, with level="medium", of the medium one),
    from one observed order for the whole field.

    coarse, medium, fine: (k, 3) displacements at the same reference points. The order is `order`'s
    if given (one order for every region of a case keeps their bands consistent), else that of the
    field's mean |u|. Monotonic: GCI_fine = Fs |u1 - u2| / (r21^q - 1), GCI_medium = Fs |u2 - u3| / (r32^q - 1)
    (Roache). Otherwise the band of either level is Fs times the larger pointwise change.
    """
    mean = order or richardson(*(np.linalg.norm(u, axis=1).mean() for u in (coarse, medium, fine)), ratio)
    if mean.kind == "monotonic":
        r32, r21 = _ratios(ratio)
        a, b, r = (fine, medium, r21) if level == "fine" else (medium, coarse, r32)
        return SAFETY * np.linalg.norm(a - b, axis=1) / (r ** min(mean.order, P_FORMAL) - 1.0), mean
    spread = np.maximum(np.linalg.norm(fine - medium, axis=1), np.linalg.norm(medium - coarse, axis=1))
    return SAFETY * spread, mean


def scaled_scene(scene: Scene, scale: float) -> Scene:
    """The scene with every mesh size (max, prostate, guide, and surface near the tip if set) multiplied by `scale`."""
    m = scene.mesh
    sizes = {k: v * scale for k, v in m.model_dump().items() if v is not None}
    return scene.model_copy(update={"mesh": m.model_copy(update=sizes)})


def study_scene(path, *, contact: bool | None = None, step_mm: float | None = None,
                volumetric: str | None = None) -> Scene:
    """The scene file, with the guide in contact or glued (effects.guide_contact), another load step
    and another volumetric term (solver.volumetric) if asked."""
    from fem_offline.scene import load_scene

    scene = load_scene(path)
    if contact is not None:
        scene = scene.model_copy(update={"effects": scene.effects.model_copy(update={"guide_contact": contact})})
    solver = {k: v for k, v in (("max_step_mm", step_mm), ("volumetric", volumetric)) if v}
    if solver:
        scene = scene.model_copy(update={"solver": scene.solver.model_copy(update=solver)})
    return scene


def probe_points(mesh, scene: Scene) -> dict[str, np.ndarray]:
    """The fixed reference points (mm) every level is evaluated at, taken from one mesh.

    markers (8, 3); prostate_surface (k, 3); interior (3, 3): the prostate's centroid and the points
    5 mm and 10 mm in front of the tip along the guide axis; nodes (n_nodes, 3): every node.
    """
    names = mesh.tissue_names
    prostate = mesh.tets[mesh.tissue == names.index("prostate"), :4]
    corners = mesh.nodes[prostate]
    volume = np.abs(np.linalg.det(corners[:, 1:] - corners[:, :1])) / 6
    centroid = (corners.mean(axis=1) * volume[:, None]).sum(axis=0) / volume.sum()
    tip, axis = np.asarray(scene.guide.tip_mm), guide_mod.direction(scene.guide, 0.0)
    return {"markers": mesh.nodes[mesh.node_sets["markers"]],
            "prostate_surface": mesh.nodes[mesh.node_sets["prostate_surface"]],
            "interior": np.stack([centroid, tip + 5.0 * axis, tip + 10.0 * axis]), "nodes": mesh.nodes}


def at_points(mesh, u: np.ndarray, points: np.ndarray) -> np.ndarray:
    """u (n_nodes, 3) interpolated at reference points (k, 3); points just outside take the nearest tet's value."""
    return interpolation_matrix(mesh.nodes, mesh.tets, points, nearest=True) @ u


def solve_resumable(problem: Problem, displacement_mm: float, angle_deg: float,
                    checkpoint: Path) -> tuple[np.ndarray, float]:
    """The nonlinear solution at one case, load-stepped from rest; every converged step is saved to
    `checkpoint`, and a later call resumes from the last one. Returns (u (n_nodes, 3), seconds spent).

    A checkpoint records its scene's hash; one of another scene (other physics, sizes or guide seat)
    is refused, not resumed (checkpoints written before the hash was recorded are taken as they are).
    """
    step = problem.scene.solver.max_step_mm
    state, seconds = None, 0.0
    sha = problem.scene.sha256()
    if checkpoint.exists():
        with np.load(checkpoint) as z:
            if "scene_sha256" in z.files and str(z["scene_sha256"]) != sha:
                raise ValueError(f"{checkpoint} is a path of another scene (sha256 {str(z['scene_sha256'])[:12]}, "
                                 f"this one {sha[:12]}); delete it or use another folder")
            history = tuple((float(d), h) for d, h in zip(z["history_d"], z["history_u"]))
            multipliers = z["multipliers"] if "multipliers" in z.files else None
            state = PathState(z["u"], float(z["d_mm"]), history, multipliers=multipliers)
            seconds = float(z["seconds"])
        if state.d_mm >= displacement_mm - 1e-12:
            return state.u.reshape(-1, 3), seconds
        log.info("resuming %g mm, %g deg from %g mm", displacement_mm, angle_deg, state.d_mm)
    start = state.d_mm if state else 0.0
    n = max(1, int(np.ceil((displacement_mm - start) / step - 1e-9)))
    targets = np.linspace(start, displacement_mm, n + 1)[1:]
    previous = list(state.history) + [(state.d_mm, state.u)] if state else []
    for d, u, stats, state in solve_path(problem, targets, angle_deg, state, with_state=True):  # noqa: B020 -- resumes from it
        seconds += stats.seconds
        previous = (previous + [(d, u.ravel())])[-3:]
        hist = previous[:-1]
        extra = {} if state.multipliers is None else {"multipliers": state.multipliers}
        atomic_savez(checkpoint, u=u.ravel(), d_mm=d, seconds=seconds, history_d=np.array([h[0] for h in hist]),
                     history_u=np.stack([h[1] for h in hist]) if hist else np.zeros((0, u.size)), scene_sha256=sha,
                     **extra)
    return u, seconds


# The hard cases (displacement_mm, angle_deg): the full push straight and tilted (beta = -10 mirrors
# +10 on the symmetric phantom), and a half push at an intermediate angle.
HARD_CASES = ((10.0, 0.0), (10.0, 10.0), (5.0, 5.0))


def run_study(scene: Scene, scales: list[float], out: Path, cases=HARD_CASES) -> dict:
    """Solve every case on every level (sizes x scale, coarsest first), resumably under `out`, and
    evaluate each at the probe points taken from the level nearest scale 1 (the default mesh).

    Returns the raw numbers: per level its tet count and solve times, per case and level the
    displacements (k, 3) at every probe point, and the probe points themselves.
    """
    from fem_offline.geometry.meshing import kept_mesh
    from fem_offline.fe.problem import build_problem

    out.mkdir(parents=True, exist_ok=True)
    meshes = [kept_mesh(scaled_scene(scene, scale), out / f"mesh_{scale:g}.npz") for scale in scales]
    reference = meshes[[abs(s - 1.0) for s in scales].index(min(abs(s - 1.0) for s in scales))]
    probes = probe_points(reference, scene)
    levels = []
    for scale, mesh in zip(scales, meshes):
        problem = build_problem(scaled_scene(scene, scale), mesh)
        level = {"scale": scale, "n_tets": len(mesh.tets), "n_nodes": len(mesh.nodes), "cases": {}}
        for d, beta in cases:
            log.info("level %g (%d tets): %g mm, %g deg", scale, len(mesh.tets), d, beta)
            u, seconds = solve_resumable(problem, d, beta, out / f"path_{scale:g}_{d:g}_{beta:g}.npz")
            level["cases"][f"{d:g} mm, {beta:g} deg"] = {
                "seconds": seconds, **{k: at_points(mesh, u, p) for k, p in probes.items()}}
        levels.append(level)
    return {"probes": probes, "levels": levels, "tip_mm": np.asarray(scene.guide.tip_mm)}


def _row(r: Richardson) -> dict:
    return {"values_mm": list(r.values), "kind": r.kind, "order": r.order, "extrapolated_mm": r.extrapolated,
            "gci_fine_mm": r.gci_fine, "gci_medium_mm": r.gci_medium}


def _level_bound(level: np.ndarray, fine: np.ndarray, fine_band: np.ndarray) -> np.ndarray:
    """Per point (k,): how far a coarser level (the medium u2, or the coarse u3) can be from the converged
    value, |u_L - u1| + GCI_fine (the triangle inequality through the fine level; for the medium level it
    is tighter than Roache's GCI_medium, which rests on the coarse level). A model built on the coarse
    level (models/default) is judged by the coarse bound."""
    return np.linalg.norm(level - fine, axis=1) + fine_band


def _summary(x: np.ndarray) -> dict:
    return {"max": float(x.max()), "p95": float(np.percentile(x, 95)), "mean": float(x.mean())} if len(x) else {}


def analyse(raw: dict) -> dict:
    """GCI of every quantity of every case from the three finest levels of `run_study`'s result.

    A level coarser than those three (a fourth level refined under the default's) is judged by the same
    bound as the medium and coarse ones, |u_L - u1| + GCI_fine point by point: `bound_by_scale_mm`, keyed
    by its scale ("1.3"), beside each quantity's medium and coarse bounds.
    """
    coarse, medium, fine = raw["levels"][-3:]
    coarser = raw["levels"][:-3]
    ratio = (coarse["scale"] / medium["scale"], medium["scale"] / fine["scale"])  # (r32, r21)
    # (the 1e-3: scales are written to 4 digits, so 0.769 / 0.5917 = 1.2996 is the ratio 1.3)
    if min(ratio) < MIN_RATIO * (1 - 1e-3) or max(ratio) > 1.01 * min(ratio):
        raise ValueError(f"levels {coarse['scale']}, {medium['scale']}, {fine['scale']}: need size ratios "
                         f">= {MIN_RATIO} and within 1 % of each other, got {ratio[0]:.4f} and {ratio[1]:.4f}")
    near = np.linalg.norm(raw["probes"]["prostate_surface"] - raw["tip_mm"], axis=1) < NEAR_TIP_MM
    out = {"ratio": ratio[1], "ratios": list(ratio),
           "levels": [{k: lv[k] for k in ("scale", "n_tets", "n_nodes")} for lv in (coarse, medium, fine)],
           "coarser_levels": [{k: lv[k] for k in ("scale", "n_tets", "n_nodes")} for lv in coarser], "cases": {}}
    for case in fine["cases"]:
        u3, u2, u1 = (lv["cases"][case] for lv in (coarse, medium, fine))
        below = {f"{lv['scale']:g}": lv["cases"][case] for lv in coarser}
        row = {"seconds": [lv["cases"][case]["seconds"] for lv in (*coarser, coarse, medium, fine)]}  # every level
        # one order per case, that of the mean |u| over every node, for every pointwise band below
        nodes_band, order = field_gci(u3["nodes"], u2["nodes"], u1["nodes"], ratio)
        nodes_medium, _ = field_gci(u3["nodes"], u2["nodes"], u1["nodes"], ratio, order, level="medium")
        row["all_nodes"] = {"n_points": len(nodes_band), "mean_order": order.order, "mean_kind": order.kind,
                            "gci_mm": _summary(nodes_band), "gci_medium_mm": _summary(nodes_medium),
                            "bound_medium_mm": _summary(_level_bound(u2["nodes"], u1["nodes"], nodes_band)),
                            "bound_coarse_mm": _summary(_level_bound(u3["nodes"], u1["nodes"], nodes_band)),
                            "bound_by_scale_mm": {s: _summary(_level_bound(u["nodes"], u1["nodes"], nodes_band))
                                                  for s, u in below.items()}}
        for group in ("markers", "interior"):
            mags = [np.linalg.norm(u[group], axis=1) for u in (u3, u2, u1)]
            band, _ = field_gci(u3[group], u2[group], u1[group], ratio, order)
            medium_band, _ = field_gci(u3[group], u2[group], u1[group], ratio, order, level="medium")
            bound, coarse_bound = _level_bound(u2[group], u1[group], band), _level_bound(u3[group], u1[group], band)
            lower = {s: _level_bound(u[group], u1[group], band) for s, u in below.items()}
            row[group] = [{**_row(richardson(a, b, c, ratio)), "gci_vector_mm": float(g),
                           "gci_vector_medium_mm": float(h), "bound_medium_mm": float(k), "bound_coarse_mm": float(m),
                           "bound_by_scale_mm": {s: float(x[i]) for s, x in lower.items()}}
                          for i, (a, b, c, g, h, k, m) in enumerate(zip(*mags, band, medium_band, bound, coarse_bound))]
        for zone, mask in (("near_tip", near), ("rest", ~near)):
            s3, s2, s1 = (u["prostate_surface"][mask] for u in (u3, u2, u1))
            mags = [np.linalg.norm(u, axis=1) for u in (s3, s2, s1)]
            band, _ = field_gci(s3, s2, s1, ratio, order)
            medium_band, _ = field_gci(s3, s2, s1, ratio, order, level="medium")
            row[f"surface_{zone}"] = {
                "n_points": int(mask.sum()), "gci_mm": _summary(band), "gci_medium_mm": _summary(medium_band),
                "change_fine_medium_mm": _summary(np.linalg.norm(s1 - s2, axis=1)),
                "bound_medium_mm": _summary(_level_bound(s2, s1, band)),
                "bound_coarse_mm": _summary(_level_bound(s3, s1, band)),
                "bound_by_scale_mm": {s: _summary(_level_bound(u["prostate_surface"][mask], s1, band))
                                      for s, u in below.items()},
                **{stat: _row(richardson(*(f(m) for m in mags), ratio))
                   for stat, f in (("max", np.max), ("p95", lambda m: np.percentile(m, 95)), ("mean", np.mean))}}
        out["cases"][case] = row
    return out


# A study folder as run_study leaves it: mesh_<scale>.npz and path_<scale>_<d>_<beta>.npz per level and case.

def level_solution(study: Path, scale: float, case: tuple[float, float], points: np.ndarray) -> np.ndarray:
    """The study's solution of `case` on level `scale`, at `points` (k, 3); refuses an unfinished path."""
    d, beta = case
    path = study / f"path_{scale:g}_{d:g}_{beta:g}.npz"
    if not path.exists():
        raise FileNotFoundError(f"{path}: the study has not solved {d:g} mm, {beta:g} deg on level {scale:g}")
    with np.load(path) as z:
        if float(z["d_mm"]) < d - 1e-9:
            raise ValueError(f"{path}: the path stopped at {float(z['d_mm']):g} mm of {d:g}; resume the study first")
        u = z["u"].reshape(-1, 3)
    return at_points(read_mesh(study / f"mesh_{scale:g}.npz"), u, points)


def solved(study: Path, scale: float, case: tuple[float, float]) -> bool:
    """Whether the study's path of `case` on level `scale` reached the case's displacement."""
    path = study / f"path_{scale:g}_{case[0]:g}_{case[1]:g}.npz"
    if not path.exists():
        return False
    with np.load(path) as z:
        return float(z["d_mm"]) >= case[0] - 1e-9


def case_levels(study: Path, scales: list[float], case: tuple[float, float]) -> list[float]:
    """The three finest of `scales` that solved `case` (a case the finest level has not solved yet is judged
    on the three below it); refuses a case with fewer than three."""
    done = [s for s in scales if solved(study, s, case)]
    if len(done) < 3:
        raise ValueError(f"{case[0]:g} mm, {case[1]:g} deg: solved on levels {done or 'none'} of {scales} in {study}; "
                         "the estimate needs three (run the study first)")
    return done[-3:]


def converged_estimate(study: Path, scales: list[float], case: tuple[float, float], points: np.ndarray,
                       order: Richardson | None = None) -> tuple[list[float], np.ndarray, np.ndarray, Richardson]:
    """The converged estimate of `case` at `points` (k, 3) from a study folder: (the three levels used,
    the fine level's answer u1 (k, 3), its GCI band (k,) in mm, the order used).

    Any other answer v at the same points (a model's, another mesh's FE) is then within
    |v - u1| + band of the converged value, point by point. The order is that of the mean |u| over
    `points` unless `order` is given (pass the one from a whole mesh's nodes to judge a few points with it).
    """
    used = case_levels(study, scales, case)
    ratio = (used[0] / used[1], used[1] / used[2])
    u3, u2, u1 = (level_solution(study, s, case, points) for s in used)
    band, order = field_gci(u3, u2, u1, ratio, order)
    return used, u1, band, order
