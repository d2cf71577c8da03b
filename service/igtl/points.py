"""The points a NeedleGuide pose is answered with: the markers, then the lesions, read from one decode.

A lesion is interpolated in its tet, x = X + sum_i N_i(X) u_i (what /predict `points` computes); a material model's
|std| at a lesion is the upper bound sum_i |N_i| std_i, as /predict's `points` give it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyigtl

from contracts.model import ModelFolder
from contracts.tet10 import p2_weights

from ..model import PointLocator, Predictor
from .devices import DIAMETER_PER_STD, MARKER_PREFIX, POINTS_NAME

MARKER_RGBA, LESION_RGBA = (255, 220, 0, 255), (230, 40, 40, 255)


class OutsidePoint(ValueError):
    """A named point lies in no tet of the mesh; the message names it."""


def marker_names(folder: ModelFolder) -> list[str]:
    return [f"{MARKER_PREFIX}{i + 1}" for i in range(len(folder.regions.get("markers", ())))]


def named_points(message) -> dict[str, np.ndarray]:
    """{name: (3,) float64} of a POINT message; ValueError for an empty, repeated or reserved name."""
    out: dict[str, np.ndarray] = {}
    for name, position in zip(message.names, message.positions):
        if not name:
            raise ValueError("a point without a name")
        if name in out:
            raise ValueError(f"{name!r} twice")
        out[name] = np.asarray(position, dtype=np.float64)
    return out


def locate_named(folder: ModelFolder, points: dict[str, np.ndarray], *, what: str) -> None:
    """OutsidePoint naming the first of `points` (reference mm) in no tet."""
    if not points:
        return
    reference = np.array(list(points.values()), dtype=np.float64).reshape(-1, 3)
    tet, _ = PointLocator(folder.nodes, folder.tets).locate(reference)
    if (tet < 0).any():
        name = list(points)[int(np.flatnonzero(tet < 0)[0])]
        raise OutsidePoint(f"{what} {name!r} {np.round(points[name], 4).tolist()} is outside the mesh")


@dataclass(frozen=True)
class PointTable:
    """The markers and the lesions of a pose's reply, and how to read them from one decode."""

    names: list[str]
    lesions: dict[str, tuple[float, float, float]]  # reference mm, by name, in order
    nodes: np.ndarray  # (n,) node ids to decode: the markers and every node of the lesions' tets
    markers: np.ndarray  # (m,) rows of `nodes` that are the markers
    lesion_nodes: np.ndarray  # (k, 10) rows of `nodes`: each lesion's tet
    weights: np.ndarray  # (k, 10) P2 weights at each lesion
    reference: np.ndarray  # (m + k, 3) float32 reference positions

    @property
    def rgba(self) -> list[tuple[int, int, int, int]]:
        return [MARKER_RGBA] * len(self.markers) + [LESION_RGBA] * len(self.lesions)

    @property
    def groups(self) -> list[str]:
        return ["markers"] * len(self.markers) + ["lesions"] * len(self.lesions)


def point_table(folder: ModelFolder, lesions: dict[str, tuple[float, float, float]]) -> PointTable:
    """The table for the model's markers and these lesions (reference mm); OutsidePoint for one in no tet."""
    markers = folder.regions["markers"]
    reference = np.asarray(list(lesions.values()), dtype=np.float64).reshape(-1, 3)
    locate_named(folder, {k: np.asarray(v) for k, v in lesions.items()}, what="lesion")
    tet, bary = PointLocator(folder.nodes, folder.tets).locate(reference)
    tet_nodes = folder.tets[tet]  # (k, 10)
    nodes, inverse = np.unique(np.concatenate([markers, tet_nodes.ravel()]), return_inverse=True)
    return PointTable(marker_names(folder) + list(lesions), dict(lesions), nodes, inverse[:len(markers)],
                      inverse[len(markers):].reshape(tet_nodes.shape), p2_weights(bary),
                      np.concatenate([folder.nodes[markers], reference]).astype(np.float32))


def positions_std(table: PointTable, predictor: Predictor, displacement_mm: float, angle_deg: float,
                  materials: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """(markers + lesions, 3) float32 deformed positions in mm, and a material model's |std| per point (mm) or None."""
    guide = np.array([[displacement_mm, angle_deg]])
    if materials is None:
        u, std = predictor.decode(guide, table.nodes)[0], None
    else:
        u, std = (a[0] for a in predictor.decode_std(guide, table.nodes, materials[None]))
    at_lesions = np.einsum("kn,knd->kd", table.weights, u[table.lesion_nodes])
    positions = table.reference + np.concatenate([u[table.markers], at_lesions]).astype(np.float32)
    if std is None:
        return positions, None
    std_lesions = np.einsum("kn,knd->kd", np.abs(table.weights), std[table.lesion_nodes])
    return positions, np.linalg.norm(np.concatenate([std[table.markers], std_lesions]), axis=1)


def deformed_points(table: PointTable, positions: np.ndarray, std: np.ndarray | None, timestamp) -> pyigtl.PointMessage:
    """POINT DeformedPoints: each point's diameter DIAMETER_PER_STD |std| for a material model."""
    # lists, not arrays: pyigtl tests `if not self.diameters`, which an array of more than one value cannot answer
    return pyigtl.PointMessage(positions=positions, names=table.names, rgba_colors=table.rgba, groups=table.groups,
                               diameters=None if std is None else (DIAMETER_PER_STD * std).tolist(),
                               device_name=POINTS_NAME, timestamp=timestamp)
