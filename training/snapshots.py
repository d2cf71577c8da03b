"""Read a sweep folder (mesh.vtu + snapshots/*.npz) or a set of solved cases into arrays."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fem_offline.mesh import TetMesh, load


@dataclass(frozen=True)
class Snapshots:
    inputs: np.ndarray  # (n, 2): displacement_mm, angle_deg
    displacement: np.ndarray  # (n, n_nodes, 3) mm, float64
    reference_positions: np.ndarray  # (n_nodes, 3) mm

    def __len__(self) -> int:
        return len(self.inputs)

    def select(self, mask: np.ndarray) -> Snapshots:
        return Snapshots(self.inputs[mask], self.displacement[mask], self.reference_positions)


@dataclass(frozen=True)
class Sweep:
    snapshots: Snapshots
    mesh: TetMesh
    manifest: dict  # the sweep's manifest.json


def read_cases(files: list[Path]) -> tuple[np.ndarray, np.ndarray]:
    """Inputs (n, 2) and displacements (n, n_nodes, 3) of solved `.npz` cases, in file order."""
    if not files:
        raise ValueError("no snapshot files")
    inputs, disp = [], []
    for f in files:
        with np.load(f) as z:
            inputs.append((float(z["displacement_mm"]), float(z["angle_deg"])))
            disp.append(z["displacement"])
    return np.asarray(inputs), np.stack(disp)


def read_sweep(folder: str | Path) -> Sweep:
    """Load a finished sweep; refuse one with missing snapshots (finish it with `fem_offline sweep`)."""
    folder = Path(folder)
    manifest_path = folder / "manifest.json"
    if not manifest_path.exists():
        raise ValueError(f"--snapshots: {folder} has no manifest.json; is it a `fem_offline sweep` output folder?")
    manifest = json.loads(manifest_path.read_text())
    files = sorted((folder / "snapshots").glob("*.npz"))
    if len(files) != manifest["n_expected"]:
        raise ValueError(
            f"--snapshots: {folder} holds {len(files)} of {manifest['n_expected']} snapshots; "
            "finish the sweep first (rerun the same `fem_offline sweep` command)"
        )
    mesh = load(folder / manifest["mesh"])
    inputs, disp = read_cases(files)
    if disp.shape[1] != len(mesh.nodes):
        raise ValueError(f"--snapshots: snapshots have {disp.shape[1]} nodes, the mesh {len(mesh.nodes)}")
    return Sweep(Snapshots(inputs, disp, mesh.nodes), mesh, manifest)
