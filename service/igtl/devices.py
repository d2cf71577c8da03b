"""The OpenIGTLink device names the server reads and sends, and what each carries: the one table of them.

`python -m service --help` prints DEVICES (devices_help); docs/viewer.md lists the same names (a test checks).
An OpenIGTLink device name has at most 20 bytes, a point's name at most 64.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass

from contracts.materials import HALO_SIGMAS

from ..estimate.aim import REACH_MM

# in
POSE_NAME = "NeedleGuide"
MATERIALS_NAME = "NeedleGuideMaterials"
LESIONS_NAME = "Lesions"
REFERENCES_NAME = "TrackedReferences"
TRACKED_NAME = "TrackedPoints"
PLAN_LESION_NAME = "PlanLesion"
# out
POINTS_NAME = "DeformedPoints"
SURFACE_NAME = "ProstateSurface"
ESTIMATED_GUIDE_NAME = "EstimatedGuide"
ESTIMATED_LESIONS_NAME = "EstimatedLesions"
ESTIMATE_REPORT_NAME = "EstimateReport"
PLANNED_GUIDE_NAME = "PlannedGuide"
PLANNED_MISS_NAME = "PlannedMiss"
PLAN_REPORT_NAME = "PlanReport"
STATUS_NAME = "NeedleGuideStatus"

MARKER_PREFIX = "marker_"  # marker_1 .. marker_8: the model's markers region, in its order, in and out
DIAMETER_PER_STD = 2.0 * HALO_SIGMAS  # a point's diameter is this x |std|: the sphere of radius HALO_SIGMAS sigma


@dataclass(frozen=True)
class Device:
    direction: str  # "in" or "out"
    type: str  # OpenIGTLink message type
    name: str
    content: str


DEVICES = (
    Device("in", "TRANSFORM", POSE_NAME, "the guide's motion from rest: rotation by beta about the tilt normal, "
           f"translation d a(beta); answered by {POINTS_NAME} (and {SURFACE_NAME})"),
    Device("in", "STRING", MATERIALS_NAME, "a material model's stiffnesses, the JSON of /predict's `materials`; held "
           "for every later message of every peer"),
    Device("in", "POINT", LESIONS_NAME, "the lesions, one named point each, reference mm; they replace "
           f"--igtl-targets and the last {LESIONS_NAME}, for every peer"),
    Device("in", "POINT", REFERENCES_NAME, "tracked points that are not markers: each name's reference position, mm; "
           "held for every peer"),
    Device("in", "POINT", TRACKED_NAME, f"tracked positions, mm: {MARKER_PREFIX}1.. for the model's markers, a "
           f"{REFERENCES_NAME} name for the others; each diameter {DIAMETER_PER_STD:g} |std| (the 2-sigma sphere; for "
           f"a per-axis std s, {DIAMETER_PER_STD:g} sqrt(3) s); "
           f"answered by {ESTIMATED_GUIDE_NAME}, {ESTIMATED_LESIONS_NAME}, {ESTIMATE_REPORT_NAME}"),
    Device("in", "POINT", PLAN_LESION_NAME, "one lesion, reference mm, to aim at; answered by "
           f"{PLANNED_GUIDE_NAME} (when reachable), {PLANNED_MISS_NAME}, {PLAN_REPORT_NAME}"),
    Device("out", "POINT", POINTS_NAME, "the markers, then each lesion, deformed at the pose (a material model: each "
           f"diameter {DIAMETER_PER_STD:g} |std|)"),
    Device("out", "POLYDATA", SURFACE_NAME, "with --igtl-surface true: the deformed prostate surface"),
    Device("out", "TRANSFORM", ESTIMATED_GUIDE_NAME, "the estimated guide pose (as NeedleGuide: its motion from rest)"),
    Device("out", "POINT", ESTIMATED_LESIONS_NAME, "each lesion's estimated displaced position, diameter "
           f"{DIAMETER_PER_STD:g} |std| (the state's posterior and the model's own error)"),
    Device("out", "STRING", ESTIMATE_REPORT_NAME, "JSON: the state with its std, the fit (rms, chi2, contradiction, "
           "outliers by point name), each lesion's std and 2-sigma bound"),
    Device("out", "TRANSFORM", PLANNED_GUIDE_NAME, "the guide pose whose needle path passes closest to the displaced "
           f"lesion; only when it passes within {REACH_MM:g} mm"),
    Device("out", "POINT", PLANNED_MISS_NAME, "the lesion displaced at that pose (diameter "
           f"{DIAMETER_PER_STD:g} x the miss's std) and the needle path's closest point to it: their distance is the "
           "miss"),
    Device("out", "STRING", PLAN_REPORT_NAME, "JSON: reachable, the message, the pose, the miss and its std, what "
           "naive aiming misses by"),
    Device("out", "STRING", STATUS_NAME,
           "why a message was refused, or that lesions, references or materials were set"),
)


def devices_help(columns: int = 100) -> str:
    """The device table as plain text, for the CLI's help."""
    width = max(len(f"{d.type} {d.name}") for d in DEVICES)
    lines = ["OpenIGTLink devices (--igtl true):"]
    for d in DEVICES:
        head = f"  {d.direction:<3} {f'{d.type} {d.name}':<{width}}  "
        lines += textwrap.wrap(d.content, columns, initial_indent=head, subsequent_indent=" " * len(head))
    return "\n".join(lines)
