"""GET /viewer: the browser 3-D viewer, served with its assets by the service itself (no CDN; works offline).

    /viewer              the page (service/static/viewer/index.html)
    /viewer/scene.json   what the page draws, fetched once: the regions to ask /predict for (null:
                         the whole mesh, where the drawn regions hold most of it anyway), each
                         tissue's reference surface with where each of its nodes arrives in those
                         replies, the markers, the guide and the envelope
    /viewer/<file>       the page's module and three.js (static/viewer/vendor/, `make viewer-assets`)

Each frame the page asks POST /predict for the few regions that hold every node it draws
(region_cover), with the binary reply (float32 little-endian, count x 3), and for its targets
with `points`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import orjson
from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import FileResponse, Response

from contracts.model import ModelFolder

from .export import surface_of
from .guide import Guide
from .model import Predictor

STATIC = Path(__file__).resolve().parent / "static" / "viewer"
MEDIA_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
               ".css": "text/css; charset=utf-8", ".png": "image/png", "": "text/plain; charset=utf-8"}
# A region cover holding this share of the mesh's nodes is replaced by one whole-mesh request.
WHOLE_MESH_FRACTION = 0.8
# Drawn in this order (translucent last); a tissue the model lacks is skipped.
TISSUES = ("prostate", "rectal_wall", "bladder", "pubic_bone", "spine", "adipose")


def region_cover(folder: ModelFolder, node_ids: np.ndarray) -> list[str]:
    """Few regions whose nodes hold all of `node_ids`: greedily the one holding most of the rest (ties: the smaller)."""
    left, chosen = set(node_ids.tolist()), []
    while left:
        name = max(sorted(folder.regions), key=lambda r: (len(left.intersection(folder.regions[r].tolist())),
                                                           -len(folder.regions[r])))
        chosen.append(name)
        left -= set(folder.regions[name].tolist())
    return chosen


def frame_requests(folder: ModelFolder, node_ids: np.ndarray) -> list[str | None]:
    """The regions a frame asks /predict for: the region cover, or [None] (the whole mesh) where it holds most of it.

    A request costs the page about 5 ms of browser and HTTP overhead whatever its size, and
    decoding and sending 10k more nodes far less (scripts/bench_viewer.py); the translucent
    fat's region alone is most of the mesh, so one whole-mesh binary request is then cheaper.
    """
    cover = region_cover(folder, node_ids)
    return [None] if sum(len(folder.regions[r]) for r in cover) >= WHOLE_MESH_FRACTION * len(folder.nodes) else cover


def gather(folder: ModelFolder, regions: list[str | None], node_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(request index, row in that reply) of each node: where its deformed position arrives in a frame."""
    source, row = np.full(len(node_ids), -1), np.zeros(len(node_ids), dtype=np.int64)
    for i, name in enumerate(regions):
        ids = np.arange(len(folder.nodes)) if name is None else folder.regions[name]
        order = np.argsort(ids)
        at = np.clip(np.searchsorted(ids, node_ids, sorter=order), 0, len(ids) - 1)
        found = (source < 0) & (ids[order[at]] == node_ids)
        source[found], row[found] = i, order[at[found]]
    assert (source >= 0).all(), "region_cover missed a node"
    return source, row


def colour_scale_mm(predictor: Predictor) -> float:
    """Top of the prostate's colour scale: its largest displacement at the envelope's corners, up to 0.5 mm."""
    (_, d_max), angles = predictor.manifest.envelope.displacement_mm, predictor.manifest.envelope.angle_deg
    prostate = predictor.folder.regions["prostate"]
    top = max(float(np.linalg.norm(predictor.displacement(d_max, a, prostate), axis=1).max()) for a in (*angles, 0.0))
    return max(0.5, float(np.ceil(2 * top) / 2))


def scene_json(predictor: Predictor) -> bytes:
    """The page's one-off download: regions to ask for, reference surfaces, markers, guide, envelope (mm, degrees)."""
    folder = predictor.folder
    manifest, guide = folder.manifest, Guide.of(folder.manifest)
    tissues = [t for t in TISSUES if t in folder.surfaces]
    surfaces = {t: surface_of(folder, t) for t in tissues}
    markers = folder.regions["markers"]
    regions = frame_requests(folder, np.unique(np.concatenate([markers, *(ids for ids, _ in surfaces.values())])))

    def layer(ids: np.ndarray) -> dict:
        source, row = gather(folder, regions, ids)
        return {"reference": folder.nodes[ids].ravel(), "source": source, "row": row}

    return orjson.dumps({
        "model": manifest.name,
        "envelope": manifest.envelope.model_dump(),
        "colour_scale_mm": colour_scale_mm(predictor),
        "regions": regions,
        "tissues": [{"name": t, "triangles": surfaces[t][1].ravel(), **layer(surfaces[t][0])} for t in tissues],
        "markers": layer(markers),
        "guide": {"tip_mm": guide.tip_mm, "axis": guide.axis, "tilt_normal": guide.tilt_normal,
                  "radius_mm": guide.patch_radius_mm},
    }, option=orjson.OPT_SERIALIZE_NUMPY)


def _files() -> dict[str, Path]:
    """Every file the viewer may serve, by its path under /viewer/ (nothing else is reachable)."""
    return {p.relative_to(STATIC).as_posix(): p for p in STATIC.rglob("*") if p.is_file()}


def viewer_router() -> APIRouter:
    """The /viewer routes; the model comes from app.state.predictor (loaded in the app's lifespan)."""
    router = APIRouter(tags=["viewer"])
    files = _files()

    def static(name: str) -> FileResponse:
        if name not in files:
            raise HTTPException(404, detail=f"no viewer file {name!r}")
        return FileResponse(files[name], media_type=MEDIA_TYPES.get(files[name].suffix, "application/octet-stream"))

    @router.get("/viewer", response_class=FileResponse)
    def page():
        """The 3-D viewer: tissue surfaces deformed live as the guide sliders move; click the prostate to add a target."""
        return static("index.html")

    @router.get("/viewer/scene.json")
    def scene(request: Request):
        """What the viewer draws, once: reference surfaces per tissue with the region to decode, markers, guide, envelope."""
        predictor = request.app.state.predictor
        if predictor is None:
            raise HTTPException(503, detail="model not loaded")
        if getattr(request.app.state, "viewer_scene", None) is None:  # built on first use, once per app
            request.app.state.viewer_scene = scene_json(predictor)
        return Response(request.app.state.viewer_scene, media_type="application/json")

    @router.get("/viewer/{name:path}", include_in_schema=False)
    def asset(name: str):
        return static(name)

    return router
