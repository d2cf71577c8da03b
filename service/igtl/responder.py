"""Turn one received OpenIGTLink message into the messages to send back (devices.py names them all).

What describes the patient (the lesions, the tracked points' reference positions, the stiffnesses) is held for
every peer until replaced, each as one immutable value swapped whole, so a peer's thread reads a consistent one.
What belongs to one connection (the last estimate, where the next fit starts, as the WebSocket stream does) is
that peer's `Peer`.
"""

from __future__ import annotations

import numpy as np
import pyigtl
from pydantic import BaseModel, ValidationError

from contracts.model import ModelFolder

from ..estimate.routes import Closing, run_estimate, run_plan
from ..guide import Guide, OffAxisPose
from ..http import RequestProblem
from ..info import ModelInfo
from ..materials import NO_MATERIALS, material_vectors, materials_request_model
from ..model import Predictor
from ..predict.export import surface_of
from .closing import RequestModels, Unusable, estimate_messages, plan_lesion, plan_messages, refusal, tracked_body
from .devices import (LESIONS_NAME, MARKER_PREFIX, MATERIALS_NAME, PLAN_LESION_NAME, POSE_NAME, REFERENCES_NAME,
                      SURFACE_NAME, TRACKED_NAME)
from .points import OutsidePoint, deformed_points, locate_named, marker_names, named_points, point_table, positions_std
from .wire import status

ENVELOPE_SLACK = 1e-3  # float32 matrices carry ~7 digits: d = 10 arrives as 10.0000002
MAX_LESIONS = 256  # EstimateReport is one STRING, at most 64 KiB; a lesion's entry takes about 100 bytes
READS = {("TRANSFORM", POSE_NAME), ("STRING", MATERIALS_NAME), ("POINT", LESIONS_NAME), ("POINT", REFERENCES_NAME),
         ("POINT", TRACKED_NAME), ("POINT", PLAN_LESION_NAME)}


class Peer:
    """One connection's own state: the last estimate (the next TrackedPoints fit starts from it)."""

    def __init__(self):
        self.state: np.ndarray | None = None


class Responder:
    """The answers of the OpenIGTLink server for one model folder."""

    def __init__(self, folder: ModelFolder, *, targets: dict[str, tuple[float, float, float]] | None = None,
                 surface: bool = False, info: ModelInfo | None = None):
        self.folder, self.guide, self.info = folder, Guide.of(folder.manifest), info
        self.envelope = folder.manifest.envelope
        self.marker_names = marker_names(folder)
        self.table = point_table(folder, dict(targets or {}))  # OutsidePoint for a target in no tet
        self.references: dict[str, np.ndarray] = {}
        self.surface = surface_of(folder, "prostate") if surface else None
        mat = folder.manifest.materials
        self._materials_model = materials_request_model(mat) if mat is not None else None
        self.materials = material_vectors(mat, None) if mat is not None else None  # (2, m): nominal, scene's std
        self.materials_given: BaseModel | None = None  # as the last NeedleGuideMaterials gave them
        self._closing: Closing | None = None
        self._models: RequestModels | None = None

    def positions(self, predictor: Predictor, displacement_mm: float, angle_deg: float) -> np.ndarray:
        """(markers + lesions, 3) float32 deformed positions in mm."""
        return positions_std(self.table, predictor, displacement_mm, angle_deg, self.materials)[0]

    def answer(self, predictor: Predictor, message, peer: Peer | None = None) -> list:
        """The messages that answer `message` (devices.py); a STRING status for anything set or refused."""
        kind = (message.message_type, message.device_name)
        if kind not in READS:
            reads = ", ".join(f"{t} {n!r}" for t, n in sorted(READS, key=lambda r: (r[0] != "TRANSFORM", r)))
            return [status(f"ignored {message.message_type} {message.device_name!r}: this server reads {reads}")]
        if kind == ("STRING", MATERIALS_NAME):
            return [status(self.set_materials(message.string))]
        if kind == ("TRANSFORM", POSE_NAME):
            return self.pose(predictor, message)
        if message.device_name == LESIONS_NAME:
            return [status(self.set_lesions(message))]
        if message.device_name == REFERENCES_NAME:
            return [status(self.set_references(message))]
        if message.device_name == TRACKED_NAME:
            return self.estimate(predictor, message, peer or Peer())
        return self.plan(predictor, message)

    # -- poses: NeedleGuide -> DeformedPoints (+ ProstateSurface)

    def guide_state(self, matrix: np.ndarray) -> tuple[float, float]:
        """(d, beta) of a NeedleGuide pose; OffAxisPose if off the family or outside the envelope."""
        d, beta = self.guide.from_pose(matrix)
        (d0, d1), (b0, b1) = self.envelope.displacement_mm, self.envelope.angle_deg
        if not (d0 - ENVELOPE_SLACK <= d <= d1 + ENVELOPE_SLACK and b0 - ENVELOPE_SLACK <= beta <= b1 + ENVELOPE_SLACK):
            raise OffAxisPose(f"displacement {d:.3f} mm, angle {beta:.3f} deg is outside the model's envelope "
                              f"({d0}..{d1} mm, {b0}..{b1} deg)")
        return min(max(d, d0), d1), min(max(beta, b0), b1)

    def pose(self, predictor: Predictor, message) -> list:
        try:
            d, beta = self.guide_state(message.matrix)
        except OffAxisPose as exc:
            return [status(f"refused {POSE_NAME}: {exc}")]
        table, materials = self.table, self.materials
        positions, std = positions_std(table, predictor, d, beta, materials)
        reply = [deformed_points(table, positions, std, message.timestamp)]
        if self.surface is not None:
            ids, triangles = self.surface
            u = (predictor.displacement(d, beta, ids) if materials is None else
                 predictor.decode_std(np.array([[d, beta]]), ids, materials[None])[0][0])
            points = self.folder.nodes[ids].astype(np.float32) + u
            polygons = np.concatenate([np.full((len(triangles), 1), 3), triangles], axis=1).ravel().astype(np.uint32)
            reply.append(pyigtl.PolyDataMessage(points=points, polygons=polygons, device_name=SURFACE_NAME,
                                                timestamp=message.timestamp))
        return reply

    # -- what describes the patient, for every peer

    def set_materials(self, text: str) -> str:
        """Take a NeedleGuideMaterials JSON object for the messages to come; the status line to send back."""
        if self._materials_model is None:
            return f"refused {MATERIALS_NAME}: {NO_MATERIALS}"
        try:
            given = self._materials_model.model_validate_json(text or "{}")
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(["materials", *map(str, err["loc"])]) if err["loc"] else "materials"
            return f"refused {MATERIALS_NAME}: {where}: {err['msg']}"
        try:
            vectors = material_vectors(self.folder.manifest.materials, given)
        except RequestProblem as exc:  # ratios outside the box: the message names the field
            return f"refused {MATERIALS_NAME}: {exc.detail}"
        self.materials, self.materials_given = vectors, given
        return f"materials set: {given.model_dump_json(exclude_none=True)}"

    def set_lesions(self, message) -> str:
        """Replace the lesions (reference mm, by name) that DeformedPoints, the estimate and the report carry."""
        try:
            lesions = named_points(message)
            if len(lesions) > MAX_LESIONS:
                raise ValueError(f"{len(lesions)} lesions (at most {MAX_LESIONS})")
            if clash := [n for n in lesions if n in self.marker_names]:
                raise ValueError(f"{clash[0]!r} is a marker's name")
            table = point_table(self.folder, {n: tuple(p.tolist()) for n, p in lesions.items()})
        except (ValueError, OutsidePoint) as exc:
            return f"refused {LESIONS_NAME}: {exc}"
        self.table = table
        return f"lesions set: {', '.join(lesions)}" if lesions else "lesions set: none"

    def set_references(self, message) -> str:
        """Replace the reference positions of the tracked points that are not markers."""
        try:
            points = named_points(message)
            if clash := [n for n in points if n.startswith(MARKER_PREFIX) and n in self.marker_names]:
                raise ValueError(f"{clash[0]!r} is a marker's name: a marker's reference is the model's")
            locate_named(self.folder, points, what="tracked point")
        except (ValueError, OutsidePoint) as exc:
            return f"refused {REFERENCES_NAME}: {exc}"
        self.references = points
        return f"tracked references set: {', '.join(points)}" if points else "tracked references set: none"

    # -- /estimate and /plan

    def closing(self, predictor: Predictor) -> tuple[Closing, RequestModels]:
        if self._closing is None or self._closing.predictor is not predictor:
            self._closing = Closing.of(predictor)
        if self._models is None:
            self._models = RequestModels.of(self.info or _info_of(self.folder))
        return self._closing, self._models

    def _materials_body(self) -> dict:
        given = self.materials_given
        return {} if given is None else {"materials": given.model_dump(exclude_none=True)}

    def estimate(self, predictor: Predictor, message, peer: Peer) -> list:
        """TrackedPoints -> EstimatedGuide, EstimatedLesions, EstimateReport: POST /estimate's fit."""
        closing, models = self.closing(predictor)
        table, references = self.table, self.references  # read once: another peer may replace them meanwhile
        lesions = list(table.lesions)
        try:
            body, names = tracked_body(message, markers=self.marker_names, references=references)
        except Unusable as exc:
            return [status(f"refused {TRACKED_NAME}: {exc}")]
        n_markers = len(body.get("markers", ()))
        targets = {"targets": [list(p) for p in table.lesions.values()]} if lesions else {}
        body.update(self._materials_body(), **targets)
        try:
            reply, peer.state = run_estimate(closing, models.estimate.model_validate(body), peer.state)
        except ValidationError as exc:
            return [status(refusal(TRACKED_NAME, exc, names, n_markers, lesions))]
        except RequestProblem as exc:
            return [status(f"refused {TRACKED_NAME}: {exc.detail}")]
        return estimate_messages(closing, reply, names=names, n_markers=n_markers, lesions=lesions,
                                 timestamp=message.timestamp)

    def plan(self, predictor: Predictor, message) -> list:
        """PlanLesion -> PlannedGuide (reachable only), PlannedMiss, PlanReport: POST /plan's aim."""
        closing, models = self.closing(predictor)
        try:
            name, lesion = plan_lesion(message)
            reply = run_plan(closing, models.plan.model_validate({"lesion_mm": lesion, **self._materials_body()}))
        except Unusable as exc:
            return [status(f"refused {PLAN_LESION_NAME}: {exc}")]
        except ValidationError as exc:
            err = exc.errors(include_input=False)[0]
            return [status(f"refused {PLAN_LESION_NAME}: {'.'.join(map(str, err['loc']))}: {err['msg']}")]
        except RequestProblem as exc:
            return [status(f"refused {PLAN_LESION_NAME}: {exc.detail}")]
        return plan_messages(reply, name=name, timestamp=message.timestamp)


def _info_of(folder: ModelFolder) -> ModelInfo:
    """The served model's info where the server was built without one (a Responder made by hand)."""
    from ..info import model_info
    from ..settings import Settings

    return model_info(folder, Settings(model=folder.path, threads=1, workers=1, batch_lanes=1, batch_max_delay_ms=0))
