"""Linear elastic tissue constants: the Lame parameters of each tet (E from shear-wave speed: scene.Tissue.youngs).

    mu     = E / (2 (1 + nu))
    lambda = E nu / ((1 + nu) (1 - 2 nu))
The neo-Hookean model (elasticity.py) uses the same mu, lambda: its small-strain limit is this one.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from fem_offline.geometry.mesh import TetMesh
    from fem_offline.scene import Scene


def lame_kpa(youngs_kpa, poisson):
    """(mu, lambda) in kPa from E (kPa) and nu; scalars or arrays."""
    return youngs_kpa / (2 * (1 + poisson)), youngs_kpa * poisson / ((1 + poisson) * (1 - 2 * poisson))


def lame(scene: Scene, mesh: TetMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-tet mu, lambda (kPa) and density (kg/m^3) from the scene's tissues; each (n_tets,)."""
    tissues = [scene.tissues[n] for n in mesh.tissue_names]
    E = np.array([t.youngs for t in tissues])[mesh.tissue]
    nu = np.array([t.poisson for t in tissues])[mesh.tissue]
    rho = np.array([t.density_kg_m3 for t in tissues])[mesh.tissue]
    mu, lam = lame_kpa(E, nu)
    return mu, lam, rho
