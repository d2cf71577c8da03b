"""Gravity (effects.gravity): the body force b = -rho g e_z on every assembled tet.

Consistent nodal load f_a = int N_a b dV. With rho in kg/m^3 and g in m/s^2, rho g is in N/m^3
= 1e-6 kPa/mm, the force density of a model in mm and kPa; f is then in kPa mm^2 = mN.
"""

from __future__ import annotations

import numpy as np

from fem_offline.fe.assembly import Pattern, assemble_vector

G_M_S2 = 9.81
N_PER_M3_IN_KPA_PER_MM = 1e-6


def body_force(*, N: np.ndarray, W: np.ndarray, density_kg_m3: np.ndarray, pattern: Pattern) -> np.ndarray:
    """f (n_dofs,) from shape values N (10, n_tets, n_qp), weights W (n_tets, n_qp) and rho (n_tets,)."""
    fz = -density_kg_m3 * G_M_S2 * N_PER_M3_IN_KPA_PER_MM  # (n_tets,) kPa/mm
    fe = np.zeros((W.shape[0], 10, 3))
    fe[:, :, 2] = np.einsum("aeq,eq->ea", N, W) * fz[:, None]
    return assemble_vector(pattern, fe)
