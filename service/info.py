"""What the service shows of its model; `model_info` is the one place that reads the manifest's keys."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import orjson

from contracts.materials import MaterialsInfo

from . import materials
from .model import ModelFolder
from .settings import Settings


@dataclass(frozen=True)
class ModelInfo:
    name: str
    displacement_mm: tuple[float, float]  # the training envelope
    angle_deg: tuple[float, float]
    regions: tuple[str, ...]  # names, sorted
    # Node bounding box, mm, wide enough for the float32 nodes GET /mesh sends to be sent back as points.
    bounds_mm: tuple[list[float], list[float]]
    summary: dict  # the GET /model reply
    mesh_json: bytes  # the GET /mesh reply
    materials: MaterialsInfo | None = None  # the stiffness inputs of a material model (service/materials.py)


def model_info(folder: ModelFolder, settings: Settings) -> ModelInfo:
    """Name, envelope, regions and bounds of a loaded model folder, and the /model and /mesh replies."""
    m, metrics = folder.manifest, folder.manifest.metrics
    nodes32 = folder.nodes.astype(np.float32)
    lo = np.minimum(folder.nodes.min(axis=0), nodes32.min(axis=0)).tolist()
    hi = np.maximum(folder.nodes.max(axis=0), nodes32.max(axis=0)).tolist()
    summary = {
        "name": m.name, "scene": m.scene.model_dump(include={"name", "sha256"}), "mesh": m.mesh.model_dump(),
        "envelope": m.envelope.model_dump(), "regions": m.regions,
        # why the envelope is smaller than the sweep's: beyond it the sweep's snapshots were not deformations
        "envelope_cut": m.envelope_cut.model_dump() if m.envelope_cut else None,
        "pca": m.pca.model_dump(include={"rank", "energy"}),
        "network": m.network.model_dump(include={"width", "depth", "activation"}),
        "fit": m.fit.model_dump(),
        "accuracy": m.accuracy.model_dump(),
        "metrics": {"table3": metrics.table3_summary.model_dump(),
                    "offgrid": metrics.offgrid_summary.model_dump() if metrics.offgrid_summary else None,
                    "angle_floor_mm": metrics.angle_floor_mm},
        "source": m.source.model_dump() if m.source else None,  # the segmentation a label-map model was built from
        "limits": {"max_points": settings.max_points, "max_body_bytes": settings.max_body_bytes},
        # the tissue stiffnesses the model takes (ranges, units, nominal, default std); null: none
        "materials": materials.summary(m.materials) if m.materials is not None else None,
    }
    mesh_json = orjson.dumps({"nodes": nodes32, "tissues": m.mesh.tissues, "surfaces": folder.surfaces},
                             option=orjson.OPT_SERIALIZE_NUMPY)
    return ModelInfo(name=m.name, displacement_mm=m.envelope.displacement_mm, angle_deg=m.envelope.angle_deg,
                     regions=tuple(sorted(m.regions)), bounds_mm=(lo, hi), summary=summary, mesh_json=mesh_json,
                     materials=m.materials)
