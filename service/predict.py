"""Predictions as arrays, alone or batched: no HTTP here (the routes turn them into replies).

A request becomes a `Query` (which nodes to decode, and how to turn their displacement into the
answer); full-mesh queries decode together in one onnxruntime call, so the basis is read once per
batch instead of once per request. Every answer is the same bytes whether batched or not.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import numpy as np

from contracts.interpolate import interpolate

from .model import Predictor
from .schemas import PredictRequestBase

ALL_NODES = "all"  # the batching key of a full-mesh query


@dataclass(frozen=True)
class Prediction:
    region: str | None  # the decoded region; None for all nodes or for points
    positions: np.ndarray  # (k, 3) float32 deformed positions, mm
    displacements: np.ndarray | None  # (k, 3) float32 mm; for markers and for points
    node_ids: np.ndarray | None  # (k,) mesh node ids; for a region


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


def plan(predictor: Predictor, request: PredictRequestBase) -> Query:
    """What a validated request decodes. Locating points is the costly part (raises OutsideMesh)."""
    guide = (request.displacement_mm, request.angle_deg)
    if request.points is not None:
        points = np.asarray(request.points, dtype=np.float64)
        unique, corners, bary = predictor.locate(points)
        # points with the same containing nodes (a viewer polling its targets) share a key
        key = "points:" + hashlib.blake2b(unique.tobytes(), digest_size=16).hexdigest()
        return Query(guide, key, unique, points=points, corners=corners, bary=bary)
    if request.region is not None:
        region = request.region.value
        return Query(guide, f"region:{region}", predictor.folder.regions[region], region=region)
    return Query(guide, ALL_NODES, None)


def finish(predictor: Predictor, query: Query, u: np.ndarray) -> Prediction:
    """The answer from the decoded displacement `u` (n, 3) of the query's nodes; may reuse `u`'s memory."""
    if query.points is not None:
        shown = interpolate(u[query.corners], query.bary).astype(np.float32)  # (k, 3)
        return Prediction(None, shown + query.points.astype(np.float32), shown, None)
    if query.region is not None:
        shown = u.copy() if query.region == "markers" else None
        return Prediction(query.region, np.add(u, predictor.nodes32[query.nodes], out=u), shown, query.nodes)
    return Prediction(None, np.add(u, predictor.nodes32, out=u), None, None)  # in place: no copy


def predict(predictor: Predictor, request: PredictRequestBase) -> Prediction:
    """Deformed positions for a validated request: all nodes, one region's nodes, or interpolated points.

    Raises OutsideMesh (from the predictor) naming the first point that lies in no tet.
    """
    query = plan(predictor, request)
    return finish(predictor, query, predictor.decode(np.array([query.guide]), query.nodes)[0])


def predict_batch(predictor: Predictor, queries: list[Query]) -> list[Prediction]:
    """The predictions of many queries: one onnxruntime call per node set among them, in their order."""
    groups: dict[str, list[int]] = {}
    for i, query in enumerate(queries):
        groups.setdefault(query.key, []).append(i)
    out: list[Prediction | None] = [None] * len(queries)
    for members in groups.values():
        first = queries[members[0]]
        if first.nodes is None:  # the full mesh: one pass over the basis for the whole batch
            u = predictor.decode(np.array([queries[i].guide for i in members]))  # (batch, n, 3)
            for row, i in enumerate(members):
                out[i] = finish(predictor, queries[i], u[row])
            continue
        # A node subset one guide at a time: its cost is the O(k * rank) gather, not the basis, and
        # onnxruntime's Gemm over a gathered (not prepacked) basis rounds the last bit differently
        # for one row than for several; so the reply is the same bytes as without batching.
        for i in members:
            out[i] = finish(predictor, queries[i], predictor.decode(np.array([queries[i].guide]), first.nodes)[0])
    return out


def decode_ms(predictor: Predictor, nodes: np.ndarray | None, *, repeats: int = 5) -> float:
    """Median wall time of one single-guide decode of `nodes` (all when None), ms."""
    guide, times = np.array([[1.0, 0.0]]), []
    predictor.decode(guide, nodes)  # the first call of a shape allocates
    for _ in range(repeats):
        t0 = time.perf_counter()
        predictor.decode(guide, nodes)
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


def cheap_keys(predictor: Predictor, budget_ms: float) -> frozenset[str]:
    """The batching keys (all nodes, each region) whose decode, measured now, takes at most `budget_ms`:
    the ones worth decoding on the event loop rather than through a thread."""
    if budget_ms <= 0:
        return frozenset()
    sets = {ALL_NODES: None, **{f"region:{name}": ids for name, ids in predictor.folder.regions.items()}}
    return frozenset(key for key, nodes in sets.items() if decode_ms(predictor, nodes) <= budget_ms)
