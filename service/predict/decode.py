"""Predictions as arrays, alone or batched: no HTTP here (pipeline.py turns them into replies).

A request becomes a `Query` (`plan`: which nodes to decode, and how to turn their displacement into the
answer); `predict_batch` decodes queries, alone or many, and full-mesh queries decode together in one
onnxruntime call, so the basis is read once per batch instead of once per request. Every answer is the
same bytes whether batched or not.
A material model's query carries its materials (theta and sigma, service/materials.py) and its answer the
std of every returned point and the error budget.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from contracts.interpolate import interpolate
from contracts.tet10 import p2_weights

from ..materials import error_budget, material_vectors
from ..model import Predictor
from .schemas import PredictRequestBase

ALL_NODES = "all"  # the batching key of a full-mesh query


@dataclass(frozen=True)
class Prediction:
    region: str | None  # the decoded region; None for all nodes or for points
    positions: np.ndarray  # (k, 3) float32 deformed positions, mm
    displacements: np.ndarray | None  # (k, 3) float32 mm; for markers and for points
    node_ids: np.ndarray | None  # (k,) mesh node ids; for a region
    std: np.ndarray | None = None  # (k, 3) float32 std of x, y, z in mm; a material model's
    budget: dict | None = None  # a material model's error budget (materials.error_budget)


@dataclass(frozen=True)
class Query:
    """One request, planned: its guide, the nodes to decode and, for points, how to interpolate them."""

    guide: tuple[float, float]  # displacement_mm, angle_deg
    key: str  # the node set's identity: queries with equal keys decode in one call
    nodes: np.ndarray | None  # (n,) node ids to decode; None for all nodes
    region: str | None = None
    points: np.ndarray | None = None  # (k, 3) float64 reference positions, mm
    corners: np.ndarray | None = None  # (k, 10) index into `nodes` of each point's tet10 nodes
    bary: np.ndarray | None = None  # (k, 4) barycentric coordinates of each point in its tet
    materials: np.ndarray | None = None  # (2, m) theta and sigma of a material model's query; None: no materials


def plan(predictor: Predictor, request: PredictRequestBase) -> Query:
    """What a validated request decodes. Locating points is the costly part (raises OutsideMesh)."""
    guide = (request.displacement_mm, request.angle_deg)
    info = predictor.manifest.materials
    materials = material_vectors(info, getattr(request, "materials", None)) if info is not None else None
    if request.points is not None:
        points = np.asarray(request.points, dtype=np.float64)
        unique, corners, bary = predictor.locate(points)
        # points with the same containing nodes (a viewer polling its targets) share a key
        key = "points:" + hashlib.blake2b(unique.tobytes(), digest_size=16).hexdigest()
        return Query(guide, key, unique, points=points, corners=corners, bary=bary, materials=materials)
    if request.region is not None:
        region = request.region.value
        return Query(guide, f"region:{region}", predictor.folder.regions[region], region=region, materials=materials)
    return Query(guide, ALL_NODES, None, materials=materials)


def decode(predictor: Predictor, queries: list[Query],
           nodes: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """(displacement, std or None), each (batch, k, 3) float32, of queries decoding the same `nodes` in one call."""
    guides = np.array([q.guide for q in queries])
    if queries[0].materials is None:
        return predictor.decode(guides, nodes), None
    return predictor.decode_std(guides, nodes, np.stack([q.materials for q in queries]))


def finish(predictor: Predictor, query: Query, u: np.ndarray, std: np.ndarray | None = None) -> Prediction:
    """The answer from the decoded displacement `u` (n, 3) of the query's nodes (and a material model's std);
    may reuse `u`'s memory."""
    if std is not None:
        return _with_std(predictor, query, finish(predictor, query, u), std)
    if query.points is not None:
        shown = interpolate(u[query.corners], query.bary).astype(np.float32)  # (k, 3)
        return Prediction(None, shown + query.points.astype(np.float32), shown, None)
    if query.region is not None:
        shown = u.copy() if query.region == "markers" else None
        return Prediction(query.region, np.add(u, predictor.nodes32[query.nodes], out=u), shown, query.nodes)
    return Prediction(None, np.add(u, predictor.nodes32, out=u), None, None)  # in place: no copy


def _with_std(predictor: Predictor, query: Query, answer: Prediction, std: np.ndarray) -> Prediction:
    """The answer with its std (k, 3) and error budget. At a point, sum_j |N_j| std_j over its tet's nodes: an upper
    bound of the interpolated field's std (triangle inequality), where the shape functions N_j may be negative."""
    if query.points is not None:
        std = np.einsum("kn,knc->kc", np.abs(p2_weights(query.bary)), std[query.corners]).astype(np.float32)
    return Prediction(answer.region, answer.positions, answer.displacements, answer.node_ids, std,
                      error_budget(predictor.budget_parts, query.region, std))


def predict_batch(predictor: Predictor, queries: list[Query]) -> list[Prediction]:
    """The predictions of many queries: one onnxruntime call per node set among them, in their order."""
    groups: dict[str, list[int]] = {}
    for i, query in enumerate(queries):
        groups.setdefault(query.key, []).append(i)
    out: list[Prediction | None] = [None] * len(queries)
    for members in groups.values():
        first = queries[members[0]]
        if first.nodes is None:  # the full mesh: one pass over the basis for the whole batch
            u, std = decode(predictor, [queries[i] for i in members], None)  # (batch, n, 3)
            for row, i in enumerate(members):
                out[i] = finish(predictor, queries[i], u[row], None if std is None else std[row])
            continue
        # A node subset one guide at a time: its cost is the O(k * rank) gather, not the basis, and
        # onnxruntime's Gemm over a gathered (not prepacked) basis rounds the last bit differently
        # for one row than for several; so the reply is the same bytes as without batching.
        for i in members:
            u, std = decode(predictor, [queries[i]], first.nodes)
            out[i] = finish(predictor, queries[i], u[0], None if std is None else std[0])
    return out


def predict(predictor: Predictor, request: PredictRequestBase) -> Prediction:
    """Deformed positions for a validated request: all nodes, one region's nodes, or interpolated points.

    Raises OutsideMesh (from the predictor) naming the first point that lies in no tet.
    """
    return predict_batch(predictor, [plan(predictor, request)])[0]
