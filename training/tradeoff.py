"""End-to-end error, online latency and build cost of a (mesh level, PCA rank, network) configuration.

The error a user sees is the model's answer against the converged FE answer, per region (max over
the region's points and the cases):

    e2e(L, r, w) = e_surrogate(r, w) + e_FE(L)

e_surrogate(r, w): the float32 ONNX model against the FE of the mesh it was fitted on, held-out cases.
e_FE(L): the FE on mesh level L against the best converged estimate of a grid-convergence study
(`python -m studies convergence-study`'s JSON, studies/convergence.py), at the study's probe points:
  the finest level     its GCI band, the best estimate's own uncertainty
  a coarser level      |u_L - u_finest| + the finest's band, at each point and case, then the max
By the triangle inequality each sum bounds the distance to the converged answer wherever the band
bounds the finest level's own error. The JSON keeps every level's displacement at the markers (and
three interior points), but the prostate surface and the whole mesh only as summaries of the three
analysed levels: the finest band and each coarser level's pointwise bound (its max over the points;
the coarse level's only in studies analysed since it was stored). So e_FE is known
  markers            on every level (pointwise sum)
  prostate_surface   on the analysed levels (the pointwise sum's max)
  all_nodes          on the analysed levels
and `level_errors` leaves a region out of a level's `fe_mm` where the JSON cannot give it.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass

import numpy as np

from contracts.model import onnx_session

from .export import build_graph
from .pca import Pca

_CASE = re.compile(r"^\s*([-+0-9.eE]+) mm, ([-+0-9.eE]+) deg\s*$")  # run_study's case keys, "10 mm, 0 deg"


@dataclass(frozen=True)
class LevelFe:
    """One mesh (a level of a convergence study, or a graded mesh judged against it): its size, its FE error per
    region (mm), its solve time."""

    scale: float | None  # the study's size multiplier; None for a graded mesh
    n_tets: int
    n_nodes: int
    fe_mm: dict[str, float]  # region -> e_FE; a region the study cannot give for this level is absent
    path_seconds: float  # mean solve time from rest of the full-push cases (the largest displacement)
    name: str = ""  # "sizes x 1.3", "graded 15.6:4:2 mm"

    @property
    def label(self) -> str:
        return self.name or f"sizes x {self.scale:g}"


def gci_bands(analysis: dict, level: str = "fine") -> dict[str, float]:
    """How far the finest level (or, level="medium" / "coarse", the second- / third-finest; or a level coarser than
    those three by its scale, "1.3") is from the converged estimate, per region (mm), max over the cases of
    `analyse`'s result: the finest level's GCI band; for a coarser level, pointwise its distance to the finest
    plus that band (convergence._level_bound)."""
    key = {"fine": ("gci_vector_mm", "gci_mm"), "medium": ("bound_medium_mm", "bound_medium_mm"),
           "coarse": ("bound_coarse_mm", "bound_coarse_mm")}.get(level)
    if key is None:
        def pick(r: dict):
            return r["bound_by_scale_mm"][level]
    else:
        def pick(r: dict):
            return r[key[0]] if key[0] in r else r[key[1]]
    rows = analysis["cases"].values()
    return {"markers": max(max(pick(r) for r in row["markers"]) for row in rows),
            "prostate_surface": max(pick(row[f"surface_{z}"])["max"] for row in rows for z in ("near_tip", "rest")),
            "all_nodes": max(pick(row["all_nodes"])["max"] for row in rows)}


def _full_push_seconds(level: dict) -> float:
    """Mean solve time of the cases at the level's largest displacement (each one a whole load path)."""
    push = {case: float(_CASE.match(case).group(1)) for case in level["cases"]}
    d_max = max(push.values())
    return float(np.mean([level["cases"][c]["seconds"] for c, d in push.items() if d == d_max]))


def graded_levels(data: dict, skipped: list[str] | None = None) -> list[LevelFe]:
    """e_FE per region for each mesh of `python -m studies graded-mesh`'s JSON, the bound `level_errors` gives a study
    level: max over the cases of |u - u_finest| + the finest's band at the study's probe points (its markers, its
    scale-1 mesh's surface nodes and every node of it).

    A mesh judged on fewer cases than the file's others is left out (its max would cover less), its tag
    appended to `skipped`."""
    if data.get("kind") != "graded_mesh":
        raise ValueError("not `python -m studies graded-mesh`'s JSON (kind is not 'graded_mesh')")
    every = set().union(*(m["cases"] for m in data["meshes"]))
    out = []
    for m in data["meshes"]:
        if set(m["cases"]) != every:
            if skipped is not None:
                skipped.append(m["tag"])
            continue
        rows = m["cases"].values()
        fe = {"markers": max(r["markers_mm"] for r in rows),
              "prostate_surface": max(r["surface_probes_mm"]["max"] for r in rows),
              "all_nodes": max(r["all_nodes_probes_mm"] for r in rows)}
        s = m["sizes_mm"]
        out.append(LevelFe(None, int(m["n_tets"]), int(m["n_nodes"]), fe, _full_push_seconds(m),
                           name=f"graded {':'.join(f'{v:g}' for v in s.values())} mm"))
    return out


def _marker_error(level: dict, finest: dict, analysis: dict) -> float:
    """max over cases and markers of |u_L - u_finest| + the finest's vector band at that marker."""
    worst = 0.0
    for case, row in analysis["cases"].items():
        band = np.array([r["gci_vector_mm"] for r in row["markers"]])  # (8,)
        gap = np.linalg.norm(np.asarray(level["cases"][case]["markers"]) - np.asarray(finest["cases"][case]["markers"]),
                             axis=1)
        worst = max(worst, float((gap + band).max()))
    return worst


def level_errors(study: dict) -> list[LevelFe]:
    """e_FE per region for every level of a convergence study's JSON (coarsest first)."""
    analysis = study["analysis"]
    key = [(lv["n_tets"], lv["n_nodes"]) for lv in analysis["levels"]]
    finest = next(lv for lv in study["levels"] if (lv["n_tets"], lv["n_nodes"]) == key[-1])
    bands = gci_bands(analysis)
    out = []
    for lv in study["levels"]:
        this = (lv["n_tets"], lv["n_nodes"])
        if this == key[-1]:
            fe = dict(bands)
        elif this == key[-2]:
            fe = gci_bands(analysis, "medium")
        elif this == key[-3] and all("bound_coarse_mm" in r for row in analysis["cases"].values()
                                     for r in row["markers"]):
            fe = gci_bands(analysis, "coarse")  # studies analysed since the coarse bound was stored
        elif f"{lv['scale']:g}" in (analysis["cases"][next(iter(analysis["cases"]))]["all_nodes"]
                                    .get("bound_by_scale_mm", {})):
            fe = gci_bands(analysis, f"{lv['scale']:g}")  # a level under the three (studies with four levels)
        else:
            fe = {"markers": _marker_error(lv, finest, analysis)}
        out.append(LevelFe(float(lv["scale"]), int(lv["n_tets"]), int(lv["n_nodes"]), fe, _full_push_seconds(lv)))
    return out


def end_to_end(surrogate_mm: dict[str, float], fe_mm: dict[str, float]) -> dict[str, float]:
    """e_surrogate + e_FE per region, for the regions both know."""
    return {k: surrogate_mm[k] + fe_mm[k] for k in surrogate_mm if k in fe_mm}


def pareto_mask(cost, error) -> np.ndarray:
    """True where no other point is at most as costly and at most as wrong, and better in one of the two."""
    c, e = np.asarray(cost, dtype=float), np.asarray(error, dtype=float)
    dominated = [bool(np.any((c <= ci) & (e <= ei) & ((c < ci) | (e < ei)))) for ci, ei in zip(c, e)]
    return ~np.array(dominated, dtype=bool)


def makespan(path_seconds, workers: int) -> float:
    """Wall time of independent paths on `workers` processes, each taking the next path when free (s)."""
    free = [0.0] * workers
    for t in path_seconds:
        i = int(np.argmin(free))
        free[i] += t
    return max(free)


def solved_path_seconds(manifest) -> list[float]:
    """Solve seconds of each path the sweep solved (mirrored snapshots cost nothing), in angle order."""
    per_angle: dict[float, float] = {}
    for s in manifest.snapshots:
        if s.mirrored_from is None:
            per_angle[s.angle_deg] = per_angle.get(s.angle_deg, 0.0) + s.seconds
    return [per_angle[a] for a in sorted(per_angle)]


def sweep_estimate(path_seconds: float, n_paths: int, workers: int) -> float:
    """Wall time of a sweep of `n_paths` equal paths of `path_seconds` each on `workers` processes (s)."""
    return math.ceil(n_paths / workers) * path_seconds


def shaped_graph(layers, n_nodes: int, *, seed: int = 0) -> bytes:
    """The exported graph of a network with a random basis for `n_nodes` nodes: the decode costs what a
    fitted model on that mesh costs, since onnxruntime's work depends on the shapes only."""
    rank = layers[-1][0].shape[1]
    rng = np.random.default_rng(seed)
    pca = Pca(mean=rng.standard_normal(3 * n_nodes), basis=rng.standard_normal((rank, 3 * n_nodes)),
              singular_values=np.ones(rank))
    return build_graph(layers, pca).SerializeToString()


def decode_seconds(model: bytes, nodes=None, *, repeat: int = 200, warmup: int = 20) -> float:
    """Median wall time of one onnxruntime call (1 thread, batch 1), all nodes or the `nodes` subset (s)."""
    sess = onnx_session(model, threads=1)
    feed = {"guide": np.array([[5.0, 2.0]], dtype=np.float32)}
    if nodes is not None:
        feed["nodes"] = np.asarray(nodes, dtype=np.int64)
    for _ in range(warmup):
        sess.run(None, feed)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        sess.run(None, feed)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))
