"""Training's view of a sweep folder (contracts.sweep): inputs and displacement fields as arrays.

A snapshot that turns an element inside out (det(I + grad u) <= 0; the linear model does so beyond a
few mm of guide push) is not a deformation, and a model must never answer with one. `valid_part`
keeps the snapshots up to the sweep's `valid_up_to_mm`, the largest displacement at which every
angle is valid, and cuts the envelope there; the model folder records the cut (EnvelopeCut).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.envelope import Envelope
from contracts.model import EnvelopeCut
from contracts.sweep import MESH_FILE, Sweep, read_cases, read_sweep, sweep_validity

__all__ = ["Snapshots", "Sweep", "read_cases", "read_offgrid", "read_sweep", "snapshots_of", "sub_grid", "valid_part"]


@dataclass(frozen=True)
class Snapshots:
    inputs: np.ndarray  # (n, 2): displacement_mm, angle_deg
    displacement: np.ndarray  # (n, n_nodes, 3) mm, float64
    reference_positions: np.ndarray  # (n_nodes, 3) mm
    sensitivity: dict[str, np.ndarray] | None = None  # tissue -> S_i (n, n_nodes, 3) mm per ln E; None: no materials

    def __len__(self) -> int:
        return len(self.inputs)

    def select(self, mask: np.ndarray) -> Snapshots:
        sens = None if self.sensitivity is None else {k: v[mask] for k, v in self.sensitivity.items()}
        return Snapshots(self.inputs[mask], self.displacement[mask], self.reference_positions, sens)


def snapshots_of(sweep: Sweep) -> Snapshots:
    return Snapshots(sweep.inputs, sweep.displacement, sweep.mesh.nodes, sweep.sensitivity)


def valid_part(sweep: Sweep) -> tuple[Snapshots, Envelope, EnvelopeCut | None]:
    """The snapshots a model may be fitted on, the envelope it answers for, and the cut (None: whole sweep).

    With an inverted snapshot anywhere, everything beyond valid_up_to_mm is left out, valid snapshots
    at other angles too, so the envelope stays a rectangle: d in [0, valid_up_to_mm] at every angle.
    ValueError when no loaded snapshot is valid, or for a linear sweep whose det F was never measured.
    """
    validity = sweep_validity(sweep.manifest)
    data, envelope = snapshots_of(sweep), sweep.manifest.envelope
    if validity.n_inverted == 0:
        return data, envelope, None
    d_max = validity.valid_up_to_mm
    keep = data.inputs[:, 0] <= d_max
    if not (data.inputs[keep, 0] > 0).any():
        first = min(d for d in validity.first_inverted_mm if d is not None)
        raise ValueError(f"--snapshots: the sweep turns an element inside out (det(I + grad u) <= 0) from its first "
                         f"displacement on ({first:g} mm): no valid snapshot to fit")
    cut = EnvelopeCut(sweep_envelope=envelope, valid_up_to_mm=d_max, n_excluded=int((~keep).sum()),
                      n_inverted=validity.n_inverted, min_det_f=validity.min_det_f)
    return data.select(keep), Envelope(displacement_mm=(0.0, d_max), angle_deg=envelope.angle_deg), cut


def read_offgrid(folder: str | Path, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """The solved cases of a `fem_offline cases` folder: inputs (n, 2), displacements (n, n_nodes, 3)."""
    files = sorted(p for p in Path(folder).glob("*.npz") if p.name != MESH_FILE)
    if not files:
        raise ValueError(f"--offgrid: no .npz cases in {folder}")
    inputs, disp = read_cases(files)
    if disp.shape[1] != n_nodes:
        raise ValueError(f"--offgrid: cases have {disp.shape[1]} nodes, the sweep's mesh {n_nodes}")
    return inputs, disp


def sub_grid(inputs: np.ndarray, angle_stride: int, disp_stride: int) -> np.ndarray:
    """Mask of the snapshots on every angle_stride-th angle from the smallest and every disp_stride-th
    displacement counted back from the largest (the 21 angles keep both ends for strides 2 and 4)."""
    angles, disps = np.unique(inputs[:, 1]), np.unique(inputs[:, 0])
    keep_a = angles[::angle_stride]
    keep_d = disps[::-1][::disp_stride]
    return np.isin(inputs[:, 1], keep_a) & np.isin(inputs[:, 0], keep_d)
