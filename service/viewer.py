"""GET /viewer: the browser 3-D viewer, served with its assets by the service itself (no CDN; works offline).

    /viewer              the page (service/static/viewer/index.html)
    /viewer/scene.json   what the page draws, fetched once: the regions to ask /predict for (null:
                         the whole mesh, where the drawn regions hold most of it anyway), each
                         tissue's reference surface with where each of its nodes arrives in those
                         replies, the markers, the guide and the envelope
    /viewer/targets      once per clicked target: its tet's 10 nodes (where each arrives in a frame's
                         replies, and its reference position) and their P2 weights at the target
    /viewer/<file>       the page's module and three.js (static/viewer/vendor/, `make viewer-assets`)

Each frame the page asks POST /predict for the few regions that hold every node it draws
(region_cover), with the binary reply (float32 little-endian, count x 3). A target is
interpolated on the page from the same replies, x = X + sum_i w_i (x_i - X_i) over its tet's
nodes, which is what /predict `points` computes; so a frame is one request with targets too.
Only a target whose tet has a node outside those regions (source -1), or a material model's targets
(for each one's std, which the binary reply does not carry: its halo), make the page ask /predict
`points` as well. A target is a lesion: the page asks POST /plan for it and draws the planned pose
(static/viewer/plan.js).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import orjson
from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import FileResponse, Response
from pydantic import BaseModel, ConfigDict, Field

from contracts.materials import HALO_SIGMAS
from contracts.model import ModelFolder
from contracts.tet10 import p2_weights

from .guide import Guide
from .http import ErrorReply
from .model import OutsideMesh, Predictor
from .predict.export import surface_of

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


def drawn_nodes(folder: ModelFolder) -> np.ndarray:
    """Sorted ids of every node the page draws: the drawn tissues' surface nodes and the markers."""
    return np.unique(np.concatenate([folder.regions["markers"], *(folder.surfaces[t].ravel() for t in TISSUES
                                                                   if t in folder.surfaces)]))


def frame_requests(folder: ModelFolder, node_ids: np.ndarray) -> list[str | None]:
    """The regions a frame asks /predict for: the region cover, or [None] (the whole mesh) where it holds most of it.

    A request costs the page a fixed browser and HTTP overhead whatever its size, and decoding and
    sending 10k more nodes far less (`python -m bench viewer`, its fetch-only rounds; CHANGELOG); the
    translucent fat's region alone is most of the mesh, so one whole-mesh binary request is then cheaper.
    """
    cover = region_cover(folder, node_ids)
    return [None] if sum(len(folder.regions[r]) for r in cover) >= WHOLE_MESH_FRACTION * len(folder.nodes) else cover


def gather(folder: ModelFolder, regions: list[str | None], node_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(request index, row in that reply) of each node: where its deformed position arrives in a frame;
    -1, 0 if nowhere."""
    source, row = np.full(len(node_ids), -1), np.zeros(len(node_ids), dtype=np.int64)
    for i, name in enumerate(regions):
        ids = np.arange(len(folder.nodes)) if name is None else folder.regions[name]
        order = np.argsort(ids)
        at = np.clip(np.searchsorted(ids, node_ids, sorter=order), 0, len(ids) - 1)
        found = (source < 0) & (ids[order[at]] == node_ids)
        source[found], row[found] = i, order[at[found]]
    return source, row


def colour_scale_mm(predictor: Predictor) -> float:
    """Top of the prostate's colour scale: its largest displacement at the envelope's corners, up to 0.5 mm."""
    (_, d_max), angles = predictor.manifest.envelope.displacement_mm, predictor.manifest.envelope.angle_deg
    prostate = predictor.folder.regions["prostate"]
    top = max(float(np.linalg.norm(predictor.displacement(d_max, a, prostate), axis=1).max()) for a in (*angles, 0.0))
    return max(0.5, float(np.ceil(2 * top) / 2))


@dataclass(frozen=True)
class Scene:
    """What the page draws: the regions a frame asks for, and scene.json's bytes."""

    regions: list[str | None]
    json: bytes


def build_scene(predictor: Predictor) -> Scene:
    """The page's one-off download: regions to ask for, reference surfaces, markers, guide, envelope (mm, degrees)."""
    folder = predictor.folder
    manifest, guide = folder.manifest, Guide.of(folder.manifest)
    tissues = [t for t in TISSUES if t in folder.surfaces]
    surfaces = {t: surface_of(folder, t) for t in tissues}
    markers = folder.regions["markers"]
    regions = frame_requests(folder, drawn_nodes(folder))

    def layer(ids: np.ndarray) -> dict:
        source, row = gather(folder, regions, ids)
        assert (source >= 0).all(), "region_cover missed a drawn node"
        return {"reference": folder.nodes[ids].ravel(), "source": source, "row": row}

    return Scene(regions, orjson.dumps({
        "model": manifest.name,
        "envelope": manifest.envelope.model_dump(),
        "colour_scale_mm": colour_scale_mm(predictor),
        "regions": regions,
        "tissues": [{"name": t, "triangles": surfaces[t][1].ravel(), **layer(surfaces[t][0])} for t in tissues],
        "markers": layer(markers),
        "guide": {"tip_mm": guide.tip_mm, "axis": guide.axis, "tilt_normal": guide.tilt_normal,
                  "radius_mm": guide.patch_radius_mm},
        # a material model's stiffness inputs: one slider each (E in kPa, within the range); null: none
        "materials": [m.model_dump(include={"tissue", "nominal_youngs_kpa", "youngs_kpa_range", "std_percent"})
                      for m in manifest.materials.inputs] if manifest.materials is not None else None,
        # a material model's halo radius in std, as OpenIGTLink's points and the error budget count it
        **({"halo_sigmas": HALO_SIGMAS} if manifest.materials is not None else {}),
    }, option=orjson.OPT_SERIALIZE_NUMPY))


Coordinate = Annotated[float, Field(strict=True, allow_inf_nan=False)]


class TargetsRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")

    points: list[tuple[Coordinate, Coordinate, Coordinate]] = Field(
        min_length=1, max_length=64, description="reference positions [x, y, z] in mm, inside the mesh")


def targets_json(predictor: Predictor, regions: list[str | None], points: np.ndarray) -> bytes:
    """Per point (k, 3) mm: its tet's 10 nodes (source, row in a frame's replies; reference mm) and P2 weights.

    The page's target is then X + sum_i w_i (x_i - X_i): /predict `points` (contracts.interpolate) on
    the frame's own replies. Raises OutsideMesh for a point in no tet.
    """
    unique, corners, bary = predictor.locate(points)
    ids = unique[corners]  # (k, 10) mesh node ids, VTK tet10 order like p2_weights
    source, row = gather(predictor.folder, regions, ids.ravel())
    weights = p2_weights(bary)  # (k, 10)
    return orjson.dumps({"targets": [
        {"source": source.reshape(ids.shape)[k], "row": row.reshape(ids.shape)[k], "weights": weights[k],
         "reference": predictor.folder.nodes[ids[k]].ravel()} for k in range(len(ids))]},
        option=orjson.OPT_SERIALIZE_NUMPY)


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
        """The 3-D viewer: tissue surfaces deformed live as the guide sliders move; click the prostate to add a target."""  # noqa: E501 -- the route's description in /openapi.json
        return static("index.html")

    def loaded(request: Request) -> tuple[Predictor, Scene]:
        predictor = request.app.state.predictor
        if predictor is None:
            raise HTTPException(503, detail="model not loaded")
        if getattr(request.app.state, "viewer_scene", None) is None:  # built on first use, once per app
            request.app.state.viewer_scene = build_scene(predictor)
        return predictor, request.app.state.viewer_scene

    @router.get("/viewer/scene.json")
    def scene(request: Request):
        """What the viewer draws, once: reference surfaces per tissue with the region to decode, markers, guide, envelope."""  # noqa: E501 -- the route's description in /openapi.json
        return Response(loaded(request)[1].json, media_type="application/json")

    @router.post("/viewer/targets", responses={
        200: {"content": {"application/json": {"schema": {"type": "object"}}},
              "description": '{"targets": [{"source", "row", "weights": 10 each, "reference": 30 mm}]} per point'},
        400: {"model": ErrorReply, "description": "the body is not readable JSON"},
        413: {"model": ErrorReply, "description": "request body too large"},
        422: {"model": ErrorReply, "description": "a point outside the mesh, or a malformed body"},
        503: {"model": ErrorReply, "description": "the model is not loaded yet"}})
    def targets(body: TargetsRequest, request: Request):
        """How the viewer interpolates targets from its frames: each point's tet nodes, where they arrive, P2 weights.

        422 for a point outside the mesh, as /predict `points`.
        """
        predictor, scene = loaded(request)
        points = np.asarray(body.points, dtype=np.float64)
        lo, hi = request.app.state.info.bounds_mm  # outside the mesh's box: no tet to look for
        off = np.flatnonzero(((points < lo) | (points > hi)).any(axis=1))
        if len(off):
            raise OutsideMesh(int(off[0]), points[off[0]].tolist())
        return Response(targets_json(predictor, scene.regions, points), media_type="application/json")

    @router.get("/viewer/{name:path}", include_in_schema=False)
    def asset(name: str):
        if name == "targets":  # POST only; without this the catch-all would answer GET with 404
            raise HTTPException(405, detail="method not allowed", headers={"Allow": "POST"})
        return static(name)

    return router
