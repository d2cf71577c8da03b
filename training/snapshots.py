"""Training's view of a sweep folder (contracts.sweep): inputs and displacement fields as arrays."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.sweep import MESH_FILE, Sweep, read_cases, read_sweep

__all__ = ["Snapshots", "Sweep", "read_cases", "read_offgrid", "read_sweep", "snapshots_of"]


@dataclass(frozen=True)
class Snapshots:
    inputs: np.ndarray  # (n, 2): displacement_mm, angle_deg
    displacement: np.ndarray  # (n, n_nodes, 3) mm, float64
    reference_positions: np.ndarray  # (n_nodes, 3) mm

    def __len__(self) -> int:
        return len(self.inputs)

    def select(self, mask: np.ndarray) -> Snapshots:
        return Snapshots(self.inputs[mask], self.displacement[mask], self.reference_positions)


def snapshots_of(sweep: Sweep) -> Snapshots:
    return Snapshots(sweep.inputs, sweep.displacement, sweep.mesh.nodes)


def read_offgrid(folder: str | Path, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """The solved cases of a `fem_offline cases` folder: inputs (n, 2), displacements (n, n_nodes, 3)."""
    files = sorted(p for p in Path(folder).glob("*.npz") if p.name != MESH_FILE)
    if not files:
        raise ValueError(f"--offgrid: no .npz cases in {folder}")
    inputs, disp = read_cases(files)
    if disp.shape[1] != n_nodes:
        raise ValueError(f"--offgrid: cases have {disp.shape[1]} nodes, the sweep's mesh {n_nodes}")
    return inputs, disp
