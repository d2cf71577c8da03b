"""A material design folder (fem_offline design -> training fit-design): design.json and one sweep folder per point.

design.json lists the points (beta_k >= 0, theta_k per tissue; theta = ln(E / E_nominal), at the box's point nearest
the nominal with those ratios) and what drew them. Each point's folder is a sweep folder (contracts.sweep) of the
scene at E_i x exp(theta_ik), swept at (-beta_k, beta_k) to the largest push on the design's one mesh; its snapshots
hold S_i = du / dtheta_i at every `sensitivity_every`-th displacement when `sensitivities`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict

from .materials import sensitivity_key
from .mesh import TetMesh, read_mesh
from .scene import RecordedScene, Scene
from .sweep import MESH_FILE, read_manifest

DESIGN_FILE = "design.json"
DESIGN_FORMAT = 1


class DesignPoint(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    folder: str  # the point's sweep folder, relative to the design's
    angle_deg: float  # beta_k >= 0; the folder also holds -beta_k
    theta: dict[str, float]  # tissue -> ln(E / E_nominal)


class Design(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    format: int = DESIGN_FORMAT
    scene_name: str
    scene_sha256: str
    kind: str  # "sobol": a scrambled Sobol sequence; "held_out": the box's corners, then Sobol points of another seed
    seed: int
    sensitivities: bool
    sensitivity_every: int  # S_i at every this-many-th displacement of a path (1: all)
    angle_max_deg: float
    tissues: list[str]
    log_box: dict[str, tuple[float, float]]  # tissue -> (lo, hi) of theta
    points: list[DesignPoint]
    scene: RecordedScene | None = None  # the base scene: the nominal stiffnesses and the box. None: not recorded yet
    # the paths' push step, mm, when not the scene's (a held-out set needs only the equilibria, not the fine path)
    displacement_step_mm: float | None = None


def read_design_file(folder: str | Path) -> Design:
    path = Path(folder) / DESIGN_FILE
    if not path.is_file():
        raise ValueError(f"{folder}: no {DESIGN_FILE}; is it a `fem_offline design` output folder?")
    return Design.model_validate_json(path.read_text())


@dataclass(frozen=True)
class DesignData:
    """Every finished snapshot of a design, its points' theta as inputs."""

    design: Design
    mesh: TetMesh
    scene: Scene  # the base scene (its nominal stiffnesses and [materials] box)
    inputs: np.ndarray  # (n, 2 + m): displacement_mm, angle_deg, theta_1 .. theta_m (design.tissues order)
    displacement: np.ndarray  # (n, n_nodes, 3) mm
    point: np.ndarray  # (n,) the design point's index
    has_sensitivity: np.ndarray  # (n,) bool
    sensitivity: np.ndarray  # (n_with, m, n_nodes, 3) mm per unit theta, of the rows with has_sensitivity
    unfinished: list[str]  # points whose paths stopped short (what they wrote is included)


def read_design(folder: str | Path, points: int | None = None) -> DesignData:
    """The snapshots on disk of every point of a design, or of its first `points` (a Sobol sequence's first 2^k
    are a design of their own); a stopped path contributes what it wrote."""
    folder = Path(folder)
    design = read_design_file(folder)
    if points is not None:
        if not 1 <= points <= len(design.points):
            raise ValueError(f"points: the design has {len(design.points)} points, asked for the first {points}")
        design = design.model_copy(update={"points": design.points[:points]})
    mesh = read_mesh(folder / MESH_FILE)
    if design.scene is None:
        raise ValueError(f"{folder}: {DESIGN_FILE} records no base scene; rerun the `fem_offline design` command once")
    rows, disp, point, has, sens, unfinished = [], [], [], [], [], []
    for k, p in enumerate(design.points):
        sub = folder / p.folder
        if not (sub / "manifest.json").is_file():
            unfinished.append(p.folder)
            continue
        manifest = read_manifest(sub)
        if manifest.n_done < manifest.n_expected:
            unfinished.append(p.folder)
        theta = [p.theta[t] for t in design.tissues]
        for record in manifest.snapshots:
            with np.load(sub / record.file) as z:
                if z["displacement"].shape[0] != len(mesh.nodes):
                    raise ValueError(f"{sub / record.file}: {z['displacement'].shape[0]} nodes, the design's mesh "
                                     f"{len(mesh.nodes)}")
                rows.append([float(z["displacement_mm"]), float(z["angle_deg"]), *theta])
                disp.append(z["displacement"])
                point.append(k)
                keys = [sensitivity_key(t) for t in design.tissues]
                has.append(all(key in z.files for key in keys))
                if has[-1]:
                    sens.append(np.stack([z[key] for key in keys]))
    if not rows:
        raise ValueError(f"{folder}: no finished snapshot yet; run the `fem_offline design` command first")
    n_nodes = len(mesh.nodes)
    return DesignData(design, mesh, design.scene, np.asarray(rows), np.stack(disp), np.asarray(point), np.asarray(has),
                      np.stack(sens) if sens else np.empty((0, len(design.tissues), n_nodes, 3)), unfinished)
