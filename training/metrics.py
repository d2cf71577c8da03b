"""The paper's accuracy metrics (Table 3, eq. 2) between predicted and FE nodal displacements."""

from __future__ import annotations

import numpy as np

from contracts.model import CaseErrors, ErrorSummary

# Nodes moving less than this are left out of the angular error: their direction is noise.
ANGLE_FLOOR_MM = 0.05

# The regions whose largest nodal error a model's manifest records (accuracy.regions, materials.accuracy).
REGIONS = ("markers", "prostate_surface", "all_nodes")


def case_errors(predicted: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """Errors of one case; both (n_nodes, 3) in mm.

    e_nn_mm: max_i |u_i - û_i| (Euclidean); alpha_deg: max angle between u_i and û_i over nodes
    with |u_i| > ANGLE_FLOOR_MM; e_r_percent: eq. 2, max_i |e_i| / max_j |y_j| x 100 over the
    3 n_nodes components; mean and p99 of the nodal error.
    """
    err = np.linalg.norm(predicted - reference, axis=1)
    ref_norm = np.linalg.norm(reference, axis=1)
    moving = ref_norm > ANGLE_FLOOR_MM
    cos = np.einsum("ij,ij->i", predicted[moving], reference[moving])
    cos /= np.linalg.norm(predicted[moving], axis=1) * ref_norm[moving]
    alpha = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max() if moving.any() else 0.0
    components = np.abs(predicted - reference).ravel()
    return {
        "e_nn_mm": float(err.max()),
        "alpha_deg": float(alpha),
        "e_r_percent": float(100.0 * components.max() / np.abs(reference).max()),
        "mean_mm": float(err.mean()),
        "p99_mm": float(np.percentile(err, 99)),
        "max_displacement_mm": float(ref_norm.max()),
    }


def summarise(rows: list[CaseErrors]) -> ErrorSummary:
    """Worst case over rows for the max metrics; mean of means."""
    return ErrorSummary(
        e_nn_mm=max(r.e_nn_mm for r in rows),
        alpha_deg=max(r.alpha_deg for r in rows),
        e_r_percent=max(r.e_r_percent for r in rows),
        mean_mm=float(np.mean([r.mean_mm for r in rows])),
        p99_mm=max(r.p99_mm for r in rows),
        n_cases=len(rows),
    )
