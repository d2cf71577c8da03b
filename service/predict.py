"""One prediction, as arrays: no HTTP here (the routes turn it into a reply)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import Predictor
from .schemas import PredictRequestBase


@dataclass(frozen=True)
class Prediction:
    region: str | None  # the decoded region; None for all nodes or for points
    positions: np.ndarray  # (k, 3) float32 deformed positions, mm
    displacements: np.ndarray | None  # (k, 3) float32 mm; for markers and for points
    node_ids: np.ndarray | None  # (k,) mesh node ids; for a region


def predict(predictor: Predictor, request: PredictRequestBase) -> Prediction:
    """Deformed positions for a validated request: all nodes, one region's nodes, or interpolated points.

    Raises OutsideMesh (from the predictor) naming the first point that lies in no tet.
    """
    d, a = request.displacement_mm, request.angle_deg
    if request.points is not None:
        reference = np.asarray(request.points, dtype=np.float64)
        u = predictor.at_points(d, a, reference)  # (k, 3) float32
        return Prediction(None, u + reference.astype(np.float32), u, None)
    if request.region is not None:
        region = request.region.value
        node_ids = predictor.folder.regions[region]
        u = predictor.displacement(d, a, node_ids)
        shown = u.copy() if region == "markers" else None
        return Prediction(region, np.add(u, predictor.nodes32[node_ids], out=u), shown, node_ids)
    u = predictor.displacement(d, a)
    return Prediction(None, np.add(u, predictor.nodes32, out=u), None, None)  # in place: no copy
