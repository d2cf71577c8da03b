"""How an equilibrium moves with each tissue's stiffness: du/d ln E_i, one tangent solve per tissue.

At equilibrium r(u; E) = 0 on the free DOFs, with u = g on the prescribed ones. At fixed nu, mu and lambda
are proportional to E, and the neo-Hookean energy (with the Taylor-Hood pressure term, a P1 pressure per
tissue) is linear in (mu, lambda), so

    d r / d ln E_i = f_i(u),      the internal force of tissue i's elements alone,
    K_T  S_i = -f_i(u)            on the free DOFs,  S_i = du/d ln E_i,  S_i = 0 where u is prescribed,

K_T the exact tangent at u (contact curvature included). f_i is taken as r(u; E_i x 2) - r(u; E), exact by
that linearity, so every element variant is covered by the residual that the solver itself uses.

With the guide prescribing displacements and gravity off, scaling every E by one factor leaves u unchanged:
only stiffness ratios matter, and sum_i S_i = 0 over the assembled tissues: exactly with the glued patch, and with
the tip in contact when its penalty scales with the wall's E (guide.contact_stiffness_per_mm); with a fixed penalty
(contact_stiffness_kpa_mm) up to its compliance.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fem_offline.fe import mixed
from fem_offline.fe.linsolve import Factor
from fem_offline.fe.newton import residual, tangent_operator
from fem_offline.fe.problem import Problem, build_problem


@dataclass(frozen=True)
class Stiffened:
    """The problem, and per soft tissue the same problem with that tissue's E doubled (built once per mesh)."""

    problem: Problem
    doubled: dict[str, Problem]

    @property
    def tissues(self) -> tuple[str, ...]:
        return tuple(self.doubled)


def soft_tissues(problem: Problem) -> tuple[str, ...]:
    """The tissues whose stiffness can move u: those with assembled (not fully constrained) tets."""
    mesh = problem.mesh
    present = np.unique(mesh.tissue[problem.active]) if problem.active is not None else np.unique(mesh.tissue)
    return tuple(mesh.tissue_names[i] for i in present)


def stiffened(problem: Problem, tissues: tuple[str, ...] | None = None) -> Stiffened:
    """Build the doubled-E problems for `tissues` (default: every soft tissue)."""
    names = soft_tissues(problem) if tissues is None else tissues
    doubled = {}
    for name in names:
        tissue = problem.scene.tissues[name]
        twice = tissue.model_copy(update={"youngs_kpa": 2.0 * tissue.youngs, "shear_wave_speed_m_s": None})
        scene = problem.scene.model_copy(update={"tissues": {**problem.scene.tissues, name: twice}})
        doubled[name] = build_problem(scene, problem.mesh)
    return Stiffened(problem, doubled)


def tissue_force(models: Stiffened, loaded: Problem, u: np.ndarray, name: str) -> np.ndarray:
    """f_i(u) (n_dofs,): d r / d ln E_i at u, with the guide and contact load of `loaded`."""
    twice = models.doubled[name]
    load = loaded.contact_load
    if load is not None and twice.contact.stiffness != loaded.contact.stiffness:
        # a penalty that scales with the wall's E (guide.contact_stiffness_per_mm): its multipliers scale with it, so
        # the contact force is of degree one in E like the tissues' forces, and sum_i f_i = r(u) exactly
        load = load._replace(multipliers=load.multipliers * (twice.contact.stiffness / loaded.contact.stiffness))
    twice = replace(twice, contact_load=load)
    return residual(twice, u).r - residual(loaded, u).r


def sensitivities(models: Stiffened, loaded: Problem, u: np.ndarray) -> dict[str, np.ndarray]:
    """S_i = du/d ln E_i (n_nodes, 3) in mm per unit ln E, at the equilibrium u (n_dofs,) of `loaded`.

    `loaded` is models.problem at the state's guide position and contact multipliers (Problem.at_guide).
    """
    K, _ = tangent_operator(loaded, u)
    factor = K.factorise(float32=False) if isinstance(K, mixed.Tangent) else Factor(K)
    free = loaded.free
    out = {}
    for name in models.tissues:
        s = np.zeros(loaded.n_dofs)
        s[free] = factor.solve(-tissue_force(models, loaded, u, name)[free])
        out[name] = s.reshape(-1, 3)
    return out


def first_order(u: np.ndarray, sens: dict[str, np.ndarray], log_ratio: dict[str, float]) -> np.ndarray:
    """u + sum_i S_i ln(E_i / E_i0): the answer at other stiffnesses, to first order in ln E."""
    return u + sum(sens[name] * log_ratio.get(name, 0.0) for name in sens)


def propagated_std(sens: dict[str, np.ndarray], log_std: dict[str, float]) -> np.ndarray:
    """Per node and component (n_nodes, 3): sqrt(sum_i (S_i sigma_i)^2), independent ln E_i with std sigma_i."""
    return np.sqrt(sum((sens[name] * log_std.get(name, 0.0)) ** 2 for name in sens))
