"""OpenIGTLink server: 3D Slicer (or any OpenIGTLink peer) sends the guide's pose and gets the deformed points back.

Off by default; `--igtl true` (env DEFORM_IGTL) serves on `--igtl-port` (18944, OpenIGTLink's port).

    in   TRANSFORM "NeedleGuide"    the guide's motion from rest: rotation by beta about the tilt normal,
                                    translation d a(beta) (service/guide.py defines the frame)
         STRING "NeedleGuideMaterials"  a material model's tissue stiffnesses, the JSON of /predict's `materials`
                                    ({"prostate": {"youngs_kpa": 70, "std_percent": 15}}; {} = nominal): they
                                    hold for every later pose, of every peer (they describe the patient);
                                    answered by a STRING status, "materials set" or why they were refused
    out  POINT "DeformedPoints"     marker_1 .. marker_8, then each configured target (`--igtl-targets
                                    '{"lesion": [x, y, z]}'`, reference mm), at their deformed positions
                                    (a material model: each point's diameter is 2 x HALO_SIGMAS x |std|, the
                                    sphere of radius 2 |std| the viewer draws as its halo, from the materials'
                                    uncertainty: contracts.materials.HALO_SIGMAS, service/materials.py)
         POLYDATA "ProstateSurface" with `--igtl-surface true`: the deformed prostate surface (triangles)
         STRING "NeedleGuideStatus" instead, when a message is refused: an off-axis pose (more than
                                    0.1 mm across the tilted axis or 0.1 deg about another axis; never
                                    projected), a pose outside the model's envelope, a bad CRC, a
                                    malformed or unsupported message. The connection and the server go on.

Messages are packed and parsed by pyigtl's message classes. pyigtl's own OpenIGTLinkServer is not
used: it installs SIGINT/SIGTERM handlers (which fails off the main thread and fights uvicorn's),
serves one peer at a time, and polls its queues every 10 ms. Here each peer gets a thread with
blocking reads, so a pose is answered as soon as it arrives.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import socketserver
import struct
import threading

import numpy as np
import pyigtl
from pydantic import ValidationError
from pyigtl.messages import CRC64

from contracts.materials import HALO_SIGMAS
from contracts.model import ModelFolder
from contracts.tet10 import p2_weights

from .guide import Guide, OffAxisPose
from .http import RequestProblem
from .materials import NO_MATERIALS, material_vectors, materials_request_model
from .model import PointLocator, Predictor
from .predict.export import surface_of

log = logging.getLogger(__name__)
POSE_NAME, POINTS_NAME, SURFACE_NAME, STATUS_NAME = "NeedleGuide", "DeformedPoints", "ProstateSurface", "NeedleGuideStatus"
MATERIALS_NAME = "NeedleGuideMaterials"
MAX_BODY_BYTES = 1 << 20  # a TRANSFORM body is 48 bytes; anything near this is not a pose
ENVELOPE_SLACK = 1e-3  # float32 matrices carry ~7 digits: d = 10 arrives as 10.0000002
MARKER_RGBA, TARGET_RGBA = (255, 220, 0, 255), (230, 40, 40, 255)


class IgtlError(ValueError):
    """The OpenIGTLink settings cannot be served (a target outside the mesh, a bad target list)."""


class Responder:
    """Turn one received OpenIGTLink message into the messages to send back."""

    def __init__(self, folder: ModelFolder, *, targets: dict[str, tuple[float, float, float]] | None = None,
                 surface: bool = False):
        self.folder, self.guide = folder, Guide.of(folder.manifest)
        self.envelope = folder.manifest.envelope
        markers = folder.regions["markers"]
        targets = targets or {}
        self.names = [f"marker_{i + 1}" for i in range(len(markers))] + list(targets)
        self.rgba = [MARKER_RGBA] * len(markers) + [TARGET_RGBA] * len(targets)
        self.groups = ["markers"] * len(markers) + ["targets"] * len(targets)
        reference = np.asarray(list(targets.values()), dtype=np.float64).reshape(-1, 3)
        tet, bary = PointLocator(folder.nodes, folder.tets).locate(reference)
        if (tet < 0).any():
            name = list(targets)[int(np.flatnonzero(tet < 0)[0])]
            raise IgtlError(f"--igtl-targets: {name!r} {targets[name]} is outside the mesh")
        # one decode per pose: the markers and every node of the targets' tets
        tet_nodes = folder.tets[tet]  # (k, 10)
        self.nodes, inverse = np.unique(np.concatenate([markers, tet_nodes.ravel()]), return_inverse=True)
        self._markers, self._targets = inverse[:len(markers)], inverse[len(markers):].reshape(tet_nodes.shape)
        self._weights = p2_weights(bary)  # (k, 10)
        self.reference = np.concatenate([folder.nodes[markers], reference]).astype(np.float32)
        self.surface = surface_of(folder, "prostate") if surface else None
        info = folder.manifest.materials
        self._materials_model = materials_request_model(info) if info is not None else None
        self.materials = material_vectors(info, None) if info is not None else None  # (2, m): nominal, scene's std

    def positions(self, predictor: Predictor, displacement_mm: float, angle_deg: float) -> np.ndarray:
        """(markers + targets, 3) float32 deformed positions in mm."""
        return self.positions_std(predictor, displacement_mm, angle_deg)[0]

    def positions_std(self, predictor: Predictor, displacement_mm: float,
                      angle_deg: float) -> tuple[np.ndarray, np.ndarray | None]:
        """(markers + targets, 3) float32 deformed positions in mm, and a material model's |std| per point (mm; at a
        target the upper bound through |N|, as /predict's points) or None."""
        guide = np.array([[displacement_mm, angle_deg]])
        if self.materials is None:
            u, std = predictor.decode(guide, self.nodes)[0], None
        else:
            u, std = (a[0] for a in predictor.decode_std(guide, self.nodes, self.materials[None]))
        at_targets = np.einsum("kn,knd->kd", self._weights, u[self._targets])
        positions = self.reference + np.concatenate([u[self._markers], at_targets]).astype(np.float32)
        if std is None:
            return positions, None
        std_targets = np.einsum("kn,knd->kd", np.abs(self._weights), std[self._targets])
        return positions, np.linalg.norm(np.concatenate([std[self._markers], std_targets]), axis=1)

    def set_materials(self, text: str) -> str:
        """Take a NeedleGuideMaterials JSON object for the poses to come; the status line to send back."""
        if self._materials_model is None:
            return f"refused {MATERIALS_NAME}: {NO_MATERIALS}"
        try:
            given = self._materials_model.model_validate_json(text or "{}")
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(["materials", *map(str, err["loc"])]) if err["loc"] else "materials"
            return f"refused {MATERIALS_NAME}: {where}: {err['msg']}"
        try:
            self.materials = material_vectors(self.folder.manifest.materials, given)
        except RequestProblem as exc:  # ratios outside the box: the message names the field
            return f"refused {MATERIALS_NAME}: {exc.detail}"
        return f"materials set: {given.model_dump_json(exclude_none=True)}"

    def guide_state(self, matrix: np.ndarray) -> tuple[float, float]:
        """(d, beta) of a NeedleGuide pose; OffAxisPose if off the family or outside the envelope."""
        d, beta = self.guide.from_pose(matrix)
        (d0, d1), (b0, b1) = self.envelope.displacement_mm, self.envelope.angle_deg
        if not (d0 - ENVELOPE_SLACK <= d <= d1 + ENVELOPE_SLACK and b0 - ENVELOPE_SLACK <= beta <= b1 + ENVELOPE_SLACK):
            raise OffAxisPose(f"displacement {d:.3f} mm, angle {beta:.3f} deg is outside the model's envelope "
                              f"({d0}..{d1} mm, {b0}..{b1} deg)")
        return min(max(d, d0), d1), min(max(beta, b0), b1)

    def answer(self, predictor: Predictor, message) -> list:
        """POINT (+ POLYDATA) for a NeedleGuide pose; a STRING status for materials and for anything refused."""
        if message.message_type == "STRING" and message.device_name == MATERIALS_NAME:
            return [status(self.set_materials(message.string))]
        if message.message_type != "TRANSFORM" or message.device_name != POSE_NAME:
            return [status(f"ignored {message.message_type} {message.device_name!r}: this server reads "
                           f"TRANSFORM {POSE_NAME!r}")]
        try:
            d, beta = self.guide_state(message.matrix)
        except OffAxisPose as exc:
            return [status(f"refused {POSE_NAME}: {exc}")]
        positions, std = self.positions_std(predictor, d, beta)
        reply = [pyigtl.PointMessage(positions=positions, names=self.names, rgba_colors=self.rgba, groups=self.groups,
                                     diameters=None if std is None else 2.0 * HALO_SIGMAS * std,
                                     device_name=POINTS_NAME, timestamp=message.timestamp)]
        if self.surface is not None:
            ids, triangles = self.surface
            u = (predictor.displacement(d, beta, ids) if self.materials is None else
                 predictor.decode_std(np.array([[d, beta]]), ids, self.materials[None])[0][0])
            points = self.folder.nodes[ids].astype(np.float32) + u
            polygons = np.concatenate([np.full((len(triangles), 1), 3), triangles], axis=1).ravel().astype(np.uint32)
            reply.append(pyigtl.PolyDataMessage(points=points, polygons=polygons, device_name=SURFACE_NAME,
                                                timestamp=message.timestamp))
        return reply


def status(text: str):
    return pyigtl.StringMessage(text, device_name=STATUS_NAME)


class Refused(ValueError):
    """One message cannot be used (bad CRC, malformed, unsupported); the stream reads on."""


class Malformed(ValueError):
    """The stream cannot be read on: the header is garbage or the body too large."""


def _read_exactly(sock: socket.socket, n: int) -> bytes | None:
    chunks, left = [], n
    while left:
        chunk = sock.recv(min(left, 1 << 16))
        if not chunk:
            return None
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


def read_message(sock: socket.socket):
    """The next message as a pyigtl message; None at EOF.

    Raises Refused for a message that cannot be used, Malformed when the stream's framing is lost.
    """
    header = _read_exactly(sock, pyigtl.MessageBase.IGTL_HEADER_SIZE)
    if header is None:
        return None
    try:
        fields = pyigtl.MessageBase.parse_header(header)
    except (UnicodeDecodeError, struct.error) as exc:
        raise Malformed(f"unreadable OpenIGTLink header ({exc})") from None
    if fields["body_size"] > MAX_BODY_BYTES:
        raise Malformed(f"message body of {fields['body_size']} bytes (at most {MAX_BODY_BYTES})")
    body = _read_exactly(sock, fields["body_size"])
    if body is None:
        return None
    if CRC64(body) != struct.unpack(">Q", header[50:58])[0]:
        raise Refused(f"refused {fields['message_type']} {fields['device_name']!r}: CRC does not match the body")
    message = pyigtl.MessageBase.create_message(fields["message_type"])
    if message is None:
        raise Refused(f"ignored {fields['message_type']} {fields['device_name']!r}: unsupported message type")
    try:
        message.unpack(fields, body)
    except Exception as exc:  # pyigtl raises struct.error, ValueError, ... on short or odd bodies
        raise Refused(f"refused {fields['message_type']} {fields['device_name']!r}: malformed body ({exc})") from None
    return message


class _Peer(socketserver.BaseRequestHandler):
    def handle(self):
        sock, server = self.request, self.server
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        server.peers.add(sock)
        log.info("OpenIGTLink peer %s:%d connected", *self.client_address[:2])
        try:
            self._serve(sock, server)
        except OSError:  # the peer went away mid-message, or stop() closed the socket
            pass
        finally:
            server.peers.discard(sock)
            log.info("OpenIGTLink peer %s:%d gone", *self.client_address[:2])

    @staticmethod
    def _serve(sock: socket.socket, server: _Server) -> None:
        while True:
            try:
                message = read_message(sock)
                if message is None:
                    return
                replies = server.responder.answer(server.predictor, message)
            except Refused as exc:
                replies = [status(str(exc))]
            except Malformed as exc:
                sock.sendall(status(f"closing the connection: {exc}").pack())
                return
            except Exception:  # a bug must not take the server down: say so and read on
                log.exception("OpenIGTLink message failed")
                replies = [status("internal error; see the service log")]
            sock.sendall(b"".join(m.pack() for m in replies))


class _Server(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    block_on_close = False
    peers: set


class IgtlServer:
    """The OpenIGTLink server, one thread per peer; `start` binds and serves, `stop` closes."""

    def __init__(self, responder: Responder, *, host: str, port: int):
        self.responder, self.host, self.port = responder, host, port
        self._server: _Server | None = None

    def start(self, predictor: Predictor) -> IgtlServer:
        server = _Server((self.host, self.port), _Peer)
        server.responder, server.predictor, server.peers = self.responder, predictor, set()
        self._server, self.port = server, server.server_address[1]
        threading.Thread(target=server.serve_forever, name="igtl", daemon=True).start()
        log.info("OpenIGTLink server on %s:%d", self.host, self.port)
        return self

    def stop(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            for sock in list(self._server.peers):  # peers see the connection close
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
            self._server = None


def igtl_server(settings, folder: ModelFolder) -> IgtlServer | None:
    """The server the settings ask for (None unless settings.igtl); IgtlError if it cannot serve them."""
    if not settings.igtl:
        return None
    responder = Responder(folder, targets=settings.igtl_targets, surface=settings.igtl_surface)
    return IgtlServer(responder, host=settings.host, port=settings.igtl_port)
