"""OpenIGTLink server: 3D Slicer (or any OpenIGTLink peer) drives the model, /estimate and /plan over a socket.

Off by default; `--igtl true` (env DEFORM_IGTL) serves on `--igtl-port` (18944, OpenIGTLink's port). The devices
and what each carries are one table, devices.DEVICES (docs/viewer.md, `python -m service --help`):

    in   TRANSFORM NeedleGuide          the guide's pose  -> POINT DeformedPoints (+ POLYDATA ProstateSurface)
         STRING NeedleGuideMaterials    the stiffnesses, held for every peer
         POINT Lesions                  the lesions, reference mm, held for every peer (replacing --igtl-targets)
         POINT TrackedReferences        the tracked points' reference positions, held for every peer
         POINT TrackedPoints            tracked markers and points -> TRANSFORM EstimatedGuide, POINT
                                        EstimatedLesions, STRING EstimateReport (POST /estimate)
         POINT PlanLesion               one lesion -> TRANSFORM PlannedGuide, POINT PlannedMiss, STRING PlanReport
                                        (POST /plan)
    out  STRING NeedleGuideStatus       instead, why a message was refused; or what was set

A pose off the guide's family (more than 0.1 mm across the tilted axis or 0.1 deg about another axis) or outside
the envelope is refused, never projected. An uncertainty travels as a point's diameter: the sphere of radius
HALO_SIGMAS x |std| (contracts.materials), in and out. A bad CRC, a malformed or unsupported message gets a
status; a connection whose framing is lost is closed; the server goes on.

    devices.py    the device names and the table
    wire.py       framing: read_message, the status STRING
    points.py     the markers and lesions of a pose's reply
    closing.py    /estimate and /plan: messages to request bodies, replies to messages
    responder.py  one message -> its answers; what is held for every peer and for one
    server.py     sockets and threads
"""

from .devices import (DEVICES, ESTIMATE_REPORT_NAME, ESTIMATED_GUIDE_NAME, ESTIMATED_LESIONS_NAME, LESIONS_NAME,
                      MATERIALS_NAME, PLAN_LESION_NAME, PLAN_REPORT_NAME, PLANNED_GUIDE_NAME, PLANNED_MISS_NAME,
                      POINTS_NAME, POSE_NAME, REFERENCES_NAME, STATUS_NAME, SURFACE_NAME, TRACKED_NAME, devices_help)
from .responder import Peer, Responder
from .server import IgtlError, IgtlServer, igtl_server
from .wire import read_message, status

__all__ = ["DEVICES", "ESTIMATE_REPORT_NAME", "ESTIMATED_GUIDE_NAME", "ESTIMATED_LESIONS_NAME", "LESIONS_NAME",
           "MATERIALS_NAME", "PLAN_LESION_NAME", "PLAN_REPORT_NAME", "PLANNED_GUIDE_NAME", "PLANNED_MISS_NAME",
           "POINTS_NAME", "POSE_NAME", "REFERENCES_NAME", "STATUS_NAME", "SURFACE_NAME", "TRACKED_NAME", "IgtlError",
           "IgtlServer", "Peer", "Responder", "devices_help", "igtl_server", "read_message", "status"]
